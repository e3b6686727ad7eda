"""Pole detection (§4.1): vertical cylinders found in horizontal sections of a guardrail run.

Following Fukano & Masuda (2015) as the paper describes it (Fig. 11): the run's points are cut by
horizontal section planes; in each section the points fall into clusters along the run; compact
clusters (a pole's cross-section, not a rail) get a circle by algebraic least squares with
iterative outlier rejection; circles that are vertically aligned are joined into a vertical
cylinder, and the pole's height runs from the ground to its highest point.

What tells a pole from the other vertical things of a guardrail:

- a pole reaches the ground; balusters and ladder stays stop at the lowest rail, 0.15-0.25 m
  above it (``max_base_height_m``);
- a pole is a straight vertical cylinder of radius ``min_radius_m`` .. ``max_radius_m``; the
  pieces of diagonal or curved pipes cut by sections drift sideways with height
  (they fit no vertical circle);
- rails cut by a section give long clusters (``max_cluster_width_m``).

Beam posts stand behind the beam and are seen only below (and on top of) it: sections through
the beam hold only long beam clusters, the cylinder is found from the sections below, which is
why only ``min_extent_share`` of the height must hold circles.

The scanner sees the front half of a pole with about 5 mm of range noise, so a single section's
circle is poor; the axis and radius come from a final geometric circle fit on all the cylinder's
inlier points projected to xy.

Modules: :mod:`.params` (the thresholds), :mod:`.stacks` (sections, clusters, stacks),
:mod:`.circles` (circle fits, RANSAC, the run's shared radius), :mod:`.ground` (a pole's foot
and the ground under it), :mod:`.detect` (:func:`detect_poles`, the steps in order).

References
----------
Matsumoto, Mori, Masuda (2019), "Extraction and shape reconstruction of guardrails using mobile
mapping data", ISPRS Archives, §4.1, Fig. 11.
Fukano, Masuda (2015), "Detection and classification of pole-like objects from mobile mapping
data", ISPRS Annals II-3/W5.
"""

from guardrail_core.reconstruct.poles.circles import fit_circles
from guardrail_core.reconstruct.poles.detect import PoleDetection, detect_poles
from guardrail_core.reconstruct.poles.params import PoleParams

__all__ = ["PoleDetection", "PoleParams", "detect_poles", "fit_circles"]
