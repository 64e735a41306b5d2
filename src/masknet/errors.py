"""The one exception type for bad user input; the CLI prints it as a single line."""


class MaskNetError(Exception):
    """Bad input or a missing resource, with a message meant for the user.

    The message names the file (when there is one) and the problem, e.g.
    ``scan.ply: 12 rows contain NaN or inf``.
    """
