"""The library's exceptions (bad input, environment problems) and how to recognise
an interrupt that arrives wrapped in another exception."""


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


def interrupted(e: BaseException) -> bool:
    """True if a KeyboardInterrupt is anywhere in ``e``'s chain of causes: Ctrl-C inside
    compiled code arrives wrapped (a numba kernel's ``SystemError: ... returned a result
    with an exception set``, a Dr.Jit error around Mitsuba's render)."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False
