"""Tuning constants of the pipeline, in one place, each with where it comes from.

Lengths are relative (to the first radius estimate ``r0`` or to the point spacing) so that a result
never depends on the units or placement of the input.
"""

import math

# --- normals -------------------------------------------------------------------------------------
#: Neighbours of the regression plane.  16 is the usual choice for PCA normals (Hoppe et al. 1992);
#: fewer makes the plane follow the noise, more blurs the cross-section on thin tubes.
NORMAL_NEIGHBOURS = 16
#: Neighbours used for the orientation spanning tree (a sparser graph suffices and is faster).
ORIENT_NEIGHBOURS = 8
#: ... and a link is only used if it is at most this many times as long as the farthest of those
#: neighbours at either end (longer links bridge two surfaces, e.g. a sparse floor and a pipe above).
ORIENT_LINK_REACH = 2.0

# --- shrinking (paper, Section 2.1 and 3) ---------------------------------------------------------
#: Break portion mu: the paper used mu >= 0.7 "for most examples".
MU = 0.7
#: tau = cos(80 deg), the paper's value for every canal example.
TAU = math.cos(math.radians(80.0))
#: Shrink step delta as a fraction of r0.  The paper's 0.2 (r = 1) and 0.05 (r = 0.3) are 1/5 - 1/6 of r;
#: a finer step locates the collapse better and costs only more cheap iterations.
DELTA_PER_RADIUS = 1 / 20
#: Neighbour radius R as a fraction of r0.  Must exceed r * (normal angle error) + noise and stay well
#: below r (NOTES); the paper's 0.2 on r = 1 is this value.
R_PER_RADIUS = 0.2
#: R must also exceed the spacing of the collapsed cloud (all points of a length-L tube on its spine);
#: this many times that spacing.
R_PER_COLLAPSED_SPACING = 3.0
#: Robust stop for Algorithm 1: the break count has peaked once it falls below this share of its maximum.
PEAK_DROP = 0.9
#: ... and a peak only counts once this share of the points break.
PEAK_MIN_SHARE = 0.1
#: Robust stop for Algorithm 2: this many moves without a newly stopped point (after half stopped) ...
PATIENCE = 3
#: ... where a move that stops fewer than this share of the points counts as stopping none: clutter and
#: stray points among tens of thousands stop a few at a time, every move, to the last, so that a scene's
#: shrinking ran to the move bound.
PATIENCE_SHARE = 5e-4
#: Shrinking never moves a point farther than this many r0 (a hard bound on the iterations).
MAX_SHRINK_PER_RADIUS = 4.0

# --- moving least squares (Section 2.2) -----------------------------------------------------------
#: Weighting radius H as a fraction of r0: must exceed the thickness of the shrunk cloud, while every
#: extra unit biases curved spines (NOTES: 0.4 - 0.6 r works for pipes).
H_PER_RADIUS = 0.6
#: The shrunk cloud is decimated on a voxel grid of this fraction of H before thinning, so that the
#: cost does not grow with the square of the points in a neighbourhood at collapse.
MLS_VOXEL_PER_H = 0.25

# --- ordering and spine ---------------------------------------------------------------------------
#: Voxel size of the thin set for ordering, as a fraction of H.
ORDER_VOXEL_PER_H = 0.5
#: Spanning-tree links longer than this many median links are cut before ordering (stray points).
ORDER_CUT_LINKS = 5.0
#: ... but never links shorter than this many voxels (3 H): a thin set only a few points per radius
#: long (a long, thin tube) has gaps of a radius that do not break the curve.
ORDER_CUT_SPACINGS = 6.0
#: Interior knot spacing of the spine spline, in r0 (the smoothing itself is chosen by GCV in the
#: refinement): spine features of a regular tube are no sharper
#: than its radius (r * curvature < 1).
SPINE_KNOTS_PER_RADIUS = 1.0
#: At least this many data points per spine spline segment, so each segment is well determined.
POINTS_PER_SEGMENT = 25
#: Interior knot spacing of the radius function, in r0.  Three radii had cost the paper's canals (Figures
#: 14 and 16) 0.4 - 0.9 % of their radius before any noise, as the truth projected onto that spline space
#: shows, and a reducer's step four times the spine error the same fit could reach (benchmarks/oracle.py);
#: the fixed light penalty keeps the finer radius from following the noise.
RADIUS_KNOTS_PER_RADIUS = 1.5
#: Second-difference penalty weight (P-spline) relative to the data term.
SMOOTHING = 1e-3

# --- refinement with all points -------------------------------------------------------------------
#: Most Gauss-Newton passes of the joint spine/radius fit (it stops earlier once converged; open ends
#: move by at most one r0 per pass, so an end far from the first guess needs several).
REFINE_ITERATIONS = 25
#: Residuals beyond this many robust standard deviations are treated as outliers.
OUTLIER_SIGMAS = 3.0
#: ... but the standard deviation is taken as at least this share of the radius: the residuals of a
#: nearly noise-free scan are the fit's own small misfit, not noise, and cutting at three times that
#: called real points near the ends stray (spine ends off by up to 0.7 r below 0.4 % noise).
MIN_SIGMA_PER_RADIUS = 0.01

# --- pipe or canal --------------------------------------------------------------------------------
#: A radius function is kept (kind "canal") only if it varies by more than this share of its mean
#: (besides winning on the Bayesian information criterion).
CANAL_MIN_VARIATION = 0.05
#: ... and by at most this factor between its narrowest and widest: one pass of shrinking works at one
#: scale, and the canals it resolves vary by a few times at most (the paper's by 2.25, a tree's stem by
#: 1.5).  A radius that goes from a pipe's to dozens of times it is a cone fitted through a pipe's end
#: and the clutter beyond, and one that reaches zero is no tube.
MAX_RADIUS_RATIO = 6.0

# --- pipeline -------------------------------------------------------------------------------------
#: mu of Algorithm 2 under the automatic stop: keep shrinking until nearly all points stopped (the
#: patience rule ends it); the paper's 0.8 stops while the thick end of a canal is still shrinking.
MU_CANAL_AUTO = 0.98
#: Larger scans run the paper's stages (normals ... ordering) on a seeded random subset of this many
#: points: with 16-neighbour patches the normals and the curvature radius get noisier as the density
#: grows (NOTES), and 5,000 points already define a tube's spine for the final fit.
MAX_SHRINK_POINTS = 5_000
#: ... unless that leaves points farther apart than this share of r0 (a long, thin tube: a fixed number
#: of points spread over 300 radii of length is only a few points around): then the subset grows to
#: reach it, up to MAX_FIT_POINTS.  A 5,000-point subset of the Figure 9 pipe is spaced 0.18 r.
MAX_SPACING_PER_RADIUS = 0.3
#: ... and fit spine and radius to at most this many (a superset of the former).  See docs/performance.md.
MAX_FIT_POINTS = 30_000
#: The RMS residual of a larger scan is estimated on a seeded sample of this many points.
MAX_RESIDUAL_POINTS = 200_000
#: A scan whose median angular coverage around the spine is below this many degrees is one-sided
#: (a full scan of 100 points per stretch reads about 340; see metrics.angular_coverage).
ONE_SIDED_DEGREES = 300.0
#: A one-sided scan's shifted points must crowd at least this many times as close at the spine as on
#: the surface (on a tube about 4 r / R = 20 times; on a blob of noise about once).
MIN_CONCENTRATION = 3.0
#: Fewer points than this share reaching the spine means the shape is not a tube.
MIN_KEPT_SHARE = 0.3

#: Points within this many times the scan's noise of a large plane found among the flat points (and
#: facing along its normal) are clutter: 3 sigma keeps 99.7 % of a plane's own points.
PLANE_TOLERANCE_NOISES = 3.0
