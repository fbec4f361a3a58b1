"""The library's exceptions (bad input, environment problems), and how to read an
exception that arrives wrapped in another: an interrupt anywhere in its chain, the
message of the error that started it."""


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


def _chain(e: BaseException | None, context: bool):
    """``e``, then its cause (or, with ``context``, the exception being handled when it
    was raised), and so on; each once."""
    seen = set()
    while e is not None and id(e) not in seen:
        yield e
        seen.add(id(e))
        e = (e.__cause__ or e.__context__) if context else e.__cause__


def interrupted(e: BaseException) -> bool:
    """True if a KeyboardInterrupt is anywhere in ``e``'s chain of causes: Ctrl-C inside
    compiled code arrives wrapped (a numba kernel's ``SystemError: ... returned a result
    with an exception set``, a Dr.Jit error around Mitsuba's render)."""
    return any(isinstance(x, KeyboardInterrupt) for x in _chain(e, context=True))


def first_cause(e: BaseException) -> BaseException:
    """The first of ``e``'s explicit causes (``raise ... from``): Dr.Jit's vectorised
    variants wrap an error raised inside a render as "drjit.custom(...): error while
    performing a custom differentiable operation. (see above)", Mitsuba's own message
    being its cause. (Not ``__context__``: that is whatever was being handled.)"""
    *_, last = _chain(e, context=False)
    return last
