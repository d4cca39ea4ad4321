"""The one exception type for bad user input.

Anything a user can get wrong (a file, an image, a parameter, a bag) raises
:class:`InputError` with a message that names the value and what was expected.
The CLI turns it into one line on stderr and exit code 2, without a traceback;
everything else is a bug and keeps its traceback.
"""


class InputError(ValueError):
    """Bad user input: the message names the value and what was expected."""
