"""User-facing errors.

Every error a user can cause (a missing file, a malformed config, a NaN pose) is an
``NsimError`` raised where the input is read, with a message that names the file and the
field. The CLI prints it as one line and exits with code 2. Internal bugs are ordinary
exceptions and keep their traceback.
"""


class NsimError(Exception):
    """A user-facing error: printed as one line by the CLI, exit code 2."""


class InputError(NsimError):
    """Bad input file or value; the message names the file and field."""


class ConfigError(NsimError):
    """Bad configuration; the message names the dotted key."""


class WorkspaceError(NsimError):
    """A workspace reference that cannot be resolved, or a workspace in a bad state."""


def name_list(names, most: int = 8) -> str:
    """``a, b, c`` for a one-line error; past ``most`` names, the first ``most`` and ``and N more`` (a bag's 300
    topics would make a 3,000-character line); ``none`` for none."""
    names = [str(n) for n in names]
    if not names:
        return "none"
    shown = ", ".join(names[:most])
    return shown if len(names) <= most else f"{shown} and {len(names) - most} more"
