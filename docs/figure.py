"""Draw docs/demo.png: the Figure 9 pipe's points, the reconstructed spine and surface.

Run from the repository root: ``python docs/figure.py`` (needs ``pip install -e ".[plot]"``).
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import canalsurf  # noqa: E402


def main(out: Path = Path(__file__).with_name("demo.png")) -> None:
    tube = canalsurf.make_tube("fig9-pipe", rng=0)
    model = canalsurf.reconstruct(tube.points)
    verts, faces = canalsurf.surface_mesh(model.spine, model.radius, closed=model.closed)
    spine, _ = model.sample(400)
    fig = plt.figure(figsize=(12, 4.2))
    panels = [("2000 input points", "points"), ("shrunk and thinned, spine", "spine"),
              ("reconstructed pipe surface", "surface")]
    for i, (title, what) in enumerate(panels, start=1):
        ax = fig.add_subplot(1, 3, i, projection="3d")
        if what == "points":
            ax.scatter(*tube.points.T, s=1, c="tab:blue")
        elif what == "spine":
            ax.scatter(*model.stages["thin"].T, s=1, c="tab:orange", alpha=0.5)
            ax.plot(*spine.T, c="k", lw=1.5)
        else:
            ax.plot_trisurf(verts[:, 0], verts[:, 1], verts[:, 2], triangles=faces, color="tab:green",
                            linewidth=0, alpha=0.9, shade=True)
        ax.set_title(title)
        ax.set_box_aspect(tuple(tube.points.max(axis=0) - tube.points.min(axis=0)))
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(out, dpi=110, bbox_inches="tight")


if __name__ == "__main__":
    main()
