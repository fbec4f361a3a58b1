"""The one library exception, raised on bad input before any work is done."""


class InvalidArgument(ValueError):
    """A parameter has a value the function cannot work with.

    The message names the parameter, the value received, the valid values, and what
    to do. The CLI prints it as one stderr line and exits with code 2.
    """


class EnvironmentProblem(RuntimeError):
    """The environment cannot do what was asked (a missing package, an unusable
    Mitsuba variant, an unreadable file). The CLI exits with code 2."""


class MissingReference(EnvironmentProblem):
    """A scene has no reference built yet (the render gate builds it on first use)."""
