"""The exceptions difflab raises: every bad input becomes one of these, with a message naming it;
and the command line's exit codes, one table for every command."""

#: Exit codes of every `difflab` command: 0 success, 1 internal error, 2 invalid input (a DifflabError,
#: one line), 3 a fit (or a batch line) that did not converge, 4 a fit flagged model_mismatch, 5 a
#: converged fit whose model was not judged -- its noise could not be estimated, or it is
#: underdetermined (results are still written for 3, 4 and 5); 130 interrupted (Ctrl-C: 128 + SIGINT,
#: as shells report it).
EXIT_OK, EXIT_INTERNAL, EXIT_INVALID, EXIT_NOT_CONVERGED, EXIT_MODEL_MISMATCH, EXIT_NOT_JUDGED = 0, 1, 2, 3, 4, 5
EXIT_INTERRUPTED = 130


class DifflabError(Exception):
    """Base class of every error difflab raises on purpose.

    Messages longer than MAX_MESSAGE characters (a user's 10,000-character key or path repeated in
    them) keep their start (the field) and end (the file), with the middle elided."""

    MAX_MESSAGE = 400

    def __init__(self, message="", *args):
        message = str(message)
        if len(message) > self.MAX_MESSAGE:
            head = self.MAX_MESSAGE * 2 // 3
            message = f"{message[:head]} [...] {message[len(message) - (self.MAX_MESSAGE - head - 7):]}"
        super().__init__(message, *args)


class SceneError(DifflabError, ValueError):
    """A scene file or scene object is invalid; the message names the field, e.g. `objects[2].radius`."""


class MeshError(DifflabError, ValueError):
    """A mesh is missing, unreadable or malformed; the message names the file."""


class TextureError(DifflabError, ValueError):
    """A texture image is missing, unreadable or malformed; the message names the file."""


class RenderError(DifflabError, ValueError):
    """A render request cannot be carried out (bad size, unknown option, device not available)."""


class OutputError(DifflabError, ValueError):
    """An output would overwrite an existing file (or a non-empty folder) and --force was not given."""


class WriteError(DifflabError, OSError):
    """An output could not be written (no permission, a full disk, a read-only file system); the
    message names the file and the reason. Also an OSError, as the failure it reports."""


class FitError(DifflabError, RuntimeError):
    """A fit was given bad input, or failed and was asked to raise (`throw=True`)."""


class ManifestError(DifflabError, ValueError):
    """A batch manifest cannot be read, or its lines are invalid; the message names the line."""

__all__ = ["DifflabError", "SceneError", "MeshError", "TextureError", "RenderError", "OutputError", "WriteError",
           "FitError", "ManifestError", "EXIT_OK", "EXIT_INTERNAL", "EXIT_INVALID", "EXIT_NOT_CONVERGED",
           "EXIT_MODEL_MISMATCH", "EXIT_NOT_JUDGED", "EXIT_INTERRUPTED"]
