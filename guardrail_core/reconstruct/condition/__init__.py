"""Condition of a reconstructed guardrail run against a standard (issue 79, assessment).

Modules: :mod:`.standards` (YAML profiles: rail-top range, post spacing, tolerances; shipped in
``standards/``, or a user's file), :mod:`.params` (:class:`ConditionParams`), :mod:`.posts`
(each post's lean, missing posts and the run's spacing), :mod:`.rail_height` (rail-top height
above the local road per segment along the run).
"""

from guardrail_core.reconstruct.condition.params import ConditionParams
from guardrail_core.reconstruct.condition.posts import (
    MissingPost,
    PostLean,
    SpacingCheck,
    missing_posts,
    post_leans,
)
from guardrail_core.reconstruct.condition.rail_height import SegmentHeight, rail_heights
from guardrail_core.reconstruct.condition.standards import (
    Standard,
    load_standard,
    shipped_standards,
)

__all__ = [
    "ConditionParams",
    "MissingPost",
    "PostLean",
    "SegmentHeight",
    "SpacingCheck",
    "Standard",
    "load_standard",
    "missing_posts",
    "post_leans",
    "rail_heights",
    "shipped_standards",
]
