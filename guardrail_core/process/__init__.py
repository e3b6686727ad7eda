"""``guardrail process``: a drive through extraction (§3) and reconstruction (§4), tile by tile,
into one run folder (:mod:`.pipeline`)."""

from guardrail_core.process.pipeline import (
    DEFAULT_MARGIN_M,
    DEFAULT_TILE_M,
    process_drive,
    process_drive_folder,
)

__all__ = ["DEFAULT_MARGIN_M", "DEFAULT_TILE_M", "process_drive", "process_drive_folder"]
