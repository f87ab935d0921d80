"""The one exception type the dispatcher treats as the user's to fix, besides ``ValueError`` and
``FileNotFoundError``: a domain package derives its own errors from :class:`UserError` (e.g.
``devices.DeviceError``: a port that is absent or mute) and the dispatcher, which imports no domain
package, prints them as one ``error: ...`` line and exits 2."""


class UserError(RuntimeError):
    """An error the user can fix (a device that is absent, a file in the wrong state); no traceback."""
