"""The project's named errors.

Every failure a user can cause (a missing file, a malformed drive, a bad scene spec) raises a
subclass of :class:`GuardrailError` whose message says what was expected and what came. The CLI
prints the message and exits with status 2 instead of a traceback.
"""

from __future__ import annotations


class GuardrailError(Exception):
    """Base of every user-facing error of the project."""


class DriveError(GuardrailError):
    """A drive folder cannot be read or written as the drive format requires."""


class MissingDriveFileError(DriveError):
    """A file the drive format requires is absent."""


class DriveFormatError(DriveError):
    """A drive file exists but its content does not follow the format (keys, types, version)."""


class DriveDimensionError(DriveError):
    """An array of the drive has the wrong shape or a LAS file lacks a required dimension."""


class TimestampMismatchError(DriveError):
    """Times of points, trajectory or images do not agree with each other."""


class NonFiniteCoordinatesError(DriveError):
    """Coordinates or times contain NaN or infinity."""


class SceneSpecError(GuardrailError):
    """A scene or design spec (YAML) is malformed or refers to something unknown."""


class InvalidOptionError(GuardrailError):
    """An option (of a command or a function) is outside its valid range."""


class OutputError(GuardrailError):
    """An output (a file or folder a command writes) cannot be written where it was asked."""


class OutputExistsError(OutputError):
    """The output folder exists and is not empty; nothing is overwritten without asking."""


class InputInsideOutputError(OutputExistsError):
    """Writing the output would delete or overwrite an input: the output is an input, holds one,
    or lies inside an input folder whose content it would replace."""


class OutputKindError(OutputExistsError):
    """The output path exists as the other kind: a file where a folder is written, or a folder
    where a file is written."""


class OutputSymlinkError(OutputError):
    """The output path is a symbolic link; replacing it would swap the link, not what it names."""


class EmptyDriveError(DriveError):
    """The drive holds no points to process (none at all, or none left after road removal)."""


class TilesFailedError(GuardrailError):
    """Every processing tile of a drive failed: there is no run to write (each tile's error is
    in the message). A run where only some tiles failed is written, and reports them."""


class ModelError(GuardrailError):
    """A classifier model folder cannot be read or used."""


class ModelFormatError(ModelError):
    """A model folder lacks a file, or a file does not follow the model format."""


class IncompatibleModelError(ModelError):
    """A model folder was written by an incompatible format version or for another architecture."""


class TrainingDataError(GuardrailError):
    """There is not enough labelled data to train (too few crops, or only one class)."""


class RunFolderError(GuardrailError):
    """A run folder is missing a file or does not match the drive it is evaluated against."""


class NotARunFolderError(RunFolderError):
    """The folder is not a run folder (it has no ``run.json``)."""


class RunFormatVersionError(RunFolderError):
    """``run.json`` was written by another format version of the run folder than this one reads."""


class NoReconstructionError(RunFolderError):
    """The run folder has no reconstruction (no ``reconstruction/models.json``)."""


class ReconstructionFormatVersionError(RunFolderError):
    """``reconstruction/models.json`` was written by another format version than this one reads."""


class ReconstructionError(GuardrailError):
    """Guardrail points cannot be reconstructed as asked (bad parameters, no guardrail at all)."""


class LabelStoreError(GuardrailError):
    """An operators' label store cannot be opened or used (not a label store, a newer schema
    version, made for another number of points, or closed)."""


class ImportSourceError(GuardrailError):
    """Data brought from elsewhere (a LAS delivery, a KITTI sequence) cannot be imported: a file
    is missing or malformed, or its parts do not fit together."""


class MissingSourceFileError(ImportSourceError):
    """A file the import needs is absent (a KITTI ``calib.txt``, a scan, a trajectory, an image)."""


class SourceFormatError(ImportSourceError):
    """A source file exists but cannot be read as its format requires (columns, keys, numbers)."""


class MissingGpsTimeError(ImportSourceError):
    """A LAS/LAZ point cloud has no ``gps_time``, so its points cannot be placed on the
    trajectory or the scan lattice."""


class PointsOutOfTimeOrderError(SourceFormatError):
    """A LAS/LAZ file of a delivery does not list its points in GPS-time order, so it cannot be
    streamed into a drive's time-ordered tiles."""


class TrajectoryCoverageError(ImportSourceError):
    """The trajectory does not cover the times of the points or images to import."""


class MissingCalibrationError(ImportSourceError):
    """Images were given without a calibration for their camera."""


class FrameRangeError(ImportSourceError):
    """Frames asked for are not in the sequence (or the frame list is malformed)."""


class ExportError(GuardrailError):
    """A run cannot be exported as asked (a mismatched drive, an output that exists)."""


class LabelsMismatchError(GuardrailError):
    """A hand-labels file does not belong to the frame it is used with."""


class StandardError(GuardrailError):
    """A guardrail standard profile (YAML) is unknown, malformed, lacks a key, or holds a value
    out of range (a minimum above its maximum, a number that is not finite)."""
