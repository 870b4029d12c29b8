"""The one exception type the pipeline raises for bad input."""


class VDNIFError(Exception):
    """A problem with the user's scene, files or settings, worded for the user.

    The message names the object or file and says what is wrong; batch commands print it
    on one line, operators pass it to ``self.report``.
    """
