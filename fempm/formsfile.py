"""Files of weak forms: the shipped ones by name, a user's own by path; their mistakes as messages.

A forms file is Python code that runs when it is loaded. The shipped files live in the
repository's ``forms/`` folder, installed with the package as ``fempm.forms``; a scene names
one of them by its bare name (``"incompressible"``), and a file of one's own is given
explicitly (``--forms PATH`` on the command line, or a path in the Python API).

Every mistake in a forms file, at import, when a form function runs or when DOLFINx
compiles what it returned, becomes one :class:`~fempm.errors.InputError` naming the
file, the function and line where Python or UFL located it, and their own sentence.
"""

from __future__ import annotations

import functools
import importlib.util
import re
import traceback
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType

import numpy as np

from fempm.errors import FempmError, InputError

__all__ = ["FORMS_DIR", "forms_path", "load_forms", "reporting_errors", "shipped_forms", "switched_on"]


def _shipped_dir() -> Path:
    """The folder of the shipped forms: the package ``fempm.forms`` (the repository's ``forms/``)."""
    spec = importlib.util.find_spec("fempm.forms")
    if spec is not None and spec.submodule_search_locations:
        return Path(list(spec.submodule_search_locations)[0]).resolve()
    return Path(__file__).resolve().parents[1] / "forms"  # a source tree on sys.path, not installed


FORMS_DIR = _shipped_dir()
_BARE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# what the named functions must return: a form linear in the test functions
_LINEAR_FORMS = ("residual", "force")


def shipped_forms() -> list[str]:
    """The names of the shipped forms files (``forms/<name>.py``)."""
    return sorted(p.stem for p in FORMS_DIR.glob("*.py") if not p.name.startswith("_"))


def forms_path(forms: str | Path, where: str = "forms") -> Path:
    """The file of ``forms``: a bare name of the shipped forms, or a path to a ``.py`` file.

    Raises:
        InputError: a name that is not shipped, a file that does not exist or is not ``.py``.
    """
    text = str(forms)
    if "\0" in text:
        raise InputError(f"{where} = {text!r}: a file name cannot hold a NUL character")
    if _BARE_NAME.fullmatch(text):
        path = FORMS_DIR / f"{text}.py"
        if not path.is_file():
            raise InputError(f"{where} = {text!r}: no shipped forms of that name; shipped: "
                             f"{', '.join(shipped_forms())}")
        return path
    path = Path(text)
    if path.suffix != ".py":
        raise InputError(f"{where} = {text!r}: not a .py file; give a Python file of forms (or a shipped "
                         f"name: {', '.join(shipped_forms())})")
    try:
        exists, is_file = path.exists(), path.is_file()
    except OSError as e:
        raise InputError(f"{where} = {text!r}: cannot be read ({e.strerror})") from None
    if not is_file:
        raise InputError(f"{where} = {text!r}: " + ("is not a file" if exists else "no such file"))
    return path.resolve()


def load_forms(path: str | Path, required: tuple[str, ...] = ()) -> ModuleType:
    """Import a forms file (a bare name: ``forms/<name>.py``) as a new module.

    The ``required`` functions are wrapped so that an error inside one, or a result that
    is not a form linear in the test functions (for ``residual`` and ``force``), raises
    :class:`InputError` naming the file, function and line.

    Raises:
        InputError: no such file, an error at import, or a required function missing.
    """
    path = forms_path(path)
    spec = importlib.util.spec_from_file_location(f"fempm_forms_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except SyntaxError as e:
        line = f", line {e.lineno}" if e.lineno else ""
        text = f" ({e.text.strip()})" if e.text and e.text.strip() else ""
        raise InputError(f"forms file {str(path)!r}{line}{text}: SyntaxError: {e.msg}") from None
    except (Exception, *_ufl_errors()) as e:  # anything the file does when it is imported
        raise InputError(_located(path, e, "at import")) from None
    missing = [name for name in required if not callable(getattr(module, name, None))]
    if missing:
        raise InputError(f"forms file {str(path)!r} does not define the function{'s' if len(missing) > 1 else ''} "
                         f"{', '.join(missing)}")
    for name in required:
        setattr(module, name, _checked(getattr(module, name), path, name))
    module.__fempm_path__ = path
    return module


def _ufl_errors() -> tuple[type[BaseException], ...]:
    """Exceptions of UFL that are not Exceptions (its arity check raises a BaseException)."""
    try:
        from ufl.algorithms.check_arities import ArityMismatch
    except ImportError:
        return ()
    return (ArityMismatch,) if not issubclass(ArityMismatch, Exception) else ()


def _checked(function, path: Path, name: str):
    """``function`` with its errors, and for a linear form a result of the wrong kind, as InputError.

    The arity of a linear form (linear in the test functions, e.g. no ``q**2``) is checked
    once, on the first call, for files other than the shipped ones: UFL finds it only while
    FFCx compiles, and a compile stopped there leaves the JIT cache waiting for it (the next
    run times out).
    """
    arity_checked = path.parent == FORMS_DIR

    @functools.wraps(function)
    def call(*args, **kwargs):
        nonlocal arity_checked
        try:
            result = function(*args, **kwargs)
        except (Exception, *_ufl_errors()) as e:  # InputError too: a field or constant that is not there
            raise InputError(_located(path, e, f"in {name}")) from None
        if name in _LINEAR_FORMS:
            problem = _not_a_linear_form(result)
            if problem is None and not arity_checked:
                problem = _arity_problem(result)
                arity_checked = problem is None
            if problem:
                raise InputError(f"forms file {str(path)!r}: {name}() {problem}")
        return result
    return call


def _arity_problem(form) -> str | None:
    """UFL's objection to ``form`` as a form linear in its arguments (None: none)."""
    from ufl.algorithms.apply_algebra_lowering import apply_algebra_lowering
    from ufl.algorithms.apply_derivatives import apply_derivatives
    from ufl.algorithms.check_arities import check_integrand_arity
    from ufl.algorithms.remove_complex_nodes import remove_complex_nodes

    try:
        lowered = remove_complex_nodes(apply_derivatives(apply_algebra_lowering(form)))
        for integral in lowered.integrals():
            check_integrand_arity(integral.integrand(), form.arguments(), False)
    except (Exception, *_ufl_errors()) as e:
        return f"is not linear in the test functions: {' '.join(str(e).split())}"
    return None


def _not_a_linear_form(result) -> str | None:
    """What is wrong with ``result`` as a form linear in the test functions (None: nothing)."""
    import ufl

    if result is None:
        return "returned None (a missing return?); it must return an integral, e.g. (...) * s.dx"
    if isinstance(result, ufl.core.expr.Expr):
        return ("returned an expression, not an integral: multiply it by a measure, s.dx or s.dx_lumped "
                "(a `* s.dx` forgotten?)")
    if not isinstance(result, ufl.Form):
        return f"returned {type(result).__name__} {result!r}, not an integral (... * s.dx)"
    numbers = {a.number() for a in result.arguments()}
    if any(n > 0 for n in numbers):
        return ("contains a trial function (s.trial): it must be linear in the test functions only; the "
                "step's unknowns are the grid function s.grid(\"U\")")
    if not numbers:
        return "contains no test function (s.test): it must be linear in the test functions"
    return None


def _located(path: Path, error: BaseException, where: str) -> str:
    """``forms file 'x.py', line 12, in continuity (source): ErrorType: message`` on one line."""
    frames = [f for f in traceback.extract_tb(error.__traceback__) if _same_file(f.filename, path)]
    if frames:
        f = frames[-1]
        place = f", line {f.lineno}, in {f.name}" + (f" ({f.line.strip()})" if f.line and f.line.strip() else "")
    else:
        place = f", {where}"
    kind = "" if isinstance(error, FempmError) else f"{type(error).__name__}: "
    message = " ".join(str(error).split()) or "(no message)"
    return f"forms file {str(path)!r}{place}: {kind}{message}"


def _same_file(name: str, path: Path) -> bool:
    try:
        return Path(name).resolve() == path
    except (OSError, ValueError):
        return False


@contextmanager
def reporting_errors(forms: str | Path):
    """Errors raised while the forms of ``forms`` are compiled, as InputError naming the file.

    Within the block, an exception raised in the forms file itself, by UFL, FFCx or
    DOLFINx's JIT, or a check of :mod:`fempm.quadrature`, names the file and, where the
    traceback passes through it, the line; other exceptions pass unchanged.
    """
    path = forms_path(forms)
    try:
        yield path
    except InputError as e:
        if str(e).startswith("forms file ") or not _passes_through(e, ("fempm/quadrature.py",)):
            raise
        raise InputError(f"forms file {str(path)!r}: {e}") from None
    except FempmError:
        raise
    except (Exception, *_ufl_errors()) as e:
        if not (_passes_through(e, ("/ufl/", "/ffcx/", "/dolfinx/jit.py", "/cffi/"))
                or any(_same_file(f.filename, path) for f in traceback.extract_tb(e.__traceback__))):
            raise
        raise InputError(_located(path, e, "when DOLFINx compiled its forms")) from None


def _passes_through(error: BaseException, parts: tuple[str, ...]) -> bool:
    return any(p in f.filename.replace("\\", "/") for f in traceback.extract_tb(error.__traceback__) for p in parts)


def switched_on(value) -> bool:
    """Whether a term multiplied by ``value`` is to be built: ``value`` non-zero now, at compilation.

    ``value`` is a constant (``s.constant("mu")``), a number, or any UFL expression of
    constants and numbers (``1.0e4 * mu``, ``ufl.sqrt(ufl.inner(g, g))``), evaluated with
    the constants' present values. Forms are compiled once per run and these values do not
    change during a run, so a term switched off stays out of the kernels.
    """
    return bool(np.any(constant_value(value) != 0))


def constant_value(value) -> np.ndarray:
    """The present value of a number, a constant or a UFL expression of constants and numbers."""
    import ufl
    from ufl.algorithms import replace
    from ufl.corealg.traversal import unique_pre_traversal

    if not isinstance(value, ufl.core.expr.Expr):
        return np.asarray(value, dtype=float)
    mapping = {}
    for node in unique_pre_traversal(value):
        if isinstance(node, ufl.Constant) and hasattr(node, "value"):
            v = np.asarray(node.value, dtype=float)
            mapping[node] = ufl.as_ufl(float(v)) if v.shape == () else ufl.as_tensor(v.tolist())
        elif isinstance(node, ufl.core.terminal.Terminal) and not isinstance(node, ufl.constantvalue.ConstantValue):
            raise InputError(f"switched_on: the expression {value} depends on {node}, which has no value at "
                             f"compilation; give a constant, a number or an expression of them")
    literal = replace(value, mapping) if mapping else value
    shape = literal.ufl_shape
    return np.array([float(literal[i] if shape else literal) for i in np.ndindex(shape)] if shape
                    else float(literal)).reshape(shape)
