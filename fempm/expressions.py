"""A small, safe expression language for fields given in scenes, e.g. ``"-100*y"``.

An expression of the position ``x``, ``y`` (m) is parsed with Python's :mod:`ast` and
evaluated on numpy arrays; nothing else runs. Allowed: numbers, ``x``, ``y``, ``pi``,
``+ - * / **``, unary minus and plus, parentheses, and the functions ``sin cos exp sqrt
tanh abs`` of one argument. No other names, no attribute access, calls, subscripts,
comparisons or keywords.
"""

from __future__ import annotations

import ast
import math
import operator

import numpy as np

__all__ = ["BadExpression", "Expression", "FUNCTIONS"]

FUNCTIONS = {"sin": np.sin, "cos": np.cos, "exp": np.exp, "sqrt": np.sqrt, "tanh": np.tanh, "abs": np.abs}
_CONSTANTS = {"pi": math.pi}
_VARIABLES = ("x", "y")
_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.Pow: operator.pow}
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos}
_MAX_LENGTH = 1000
_MAX_DEPTH = 50
ALLOWED = "numbers, x, y, pi, + - * / **, parentheses and " + " ".join(FUNCTIONS)


class BadExpression(ValueError):
    """An expression outside the language; the message names the offending token."""


class Expression:
    """A parsed expression; call it with positions ``(n, 2)`` to get one value per point."""

    def __init__(self, text: str):
        if not isinstance(text, str):
            raise BadExpression(f"must be a number or an expression in x and y, got {text!r}")
        if len(text) > _MAX_LENGTH:
            raise BadExpression(f"is longer than {_MAX_LENGTH} characters")
        try:
            tree = ast.parse(text.strip(), mode="eval")
        except SyntaxError as e:
            raise BadExpression(f"{text!r} is not an expression ({e.msg}); allowed: {ALLOWED}") from None
        self.text = text
        self._source = text.strip()
        self._tree = tree.body
        self._check(self._tree, 0)

    def _token(self, node: ast.AST) -> str:
        return ast.get_source_segment(self._source, node) or type(node).__name__

    def _check(self, node: ast.AST, depth: int):
        if depth > _MAX_DEPTH:
            raise BadExpression(f"{self.text!r} is nested more than {_MAX_DEPTH} deep")
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, int | float):
                raise BadExpression(f"{self.text!r}: {self._token(node)!r} is not allowed (not a number); "
                                    f"allowed: {ALLOWED}")
        elif isinstance(node, ast.Name):
            if node.id not in _VARIABLES and node.id not in _CONSTANTS:
                raise BadExpression(f"{self.text!r}: the name {node.id!r} is not allowed; allowed: {ALLOWED}")
        elif isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            self._check(node.left, depth + 1)
            self._check(node.right, depth + 1)
        elif isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
            self._check(node.operand, depth + 1)
        elif isinstance(node, ast.Call):
            if not (isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS):
                self._refuse(node.func, "one of the functions")
            if len(node.args) != 1 or node.keywords:
                self._refuse(node, "a call of one argument")
            self._check(node.args[0], depth + 1)
        else:
            self._refuse(node, "")

    def _refuse(self, node: ast.AST, wanted: str):
        what = {ast.Attribute: "attribute access", ast.Subscript: "indexing", ast.Compare: "a comparison",
                ast.BoolOp: "a logical operator", ast.Lambda: "a lambda"}.get(type(node), "")
        token = self._token(node)
        detail = f" (not {wanted})" if wanted else (f" ({what})" if what else "")
        raise BadExpression(f"{self.text!r}: {token!r}{detail} is not allowed; allowed: {ALLOWED}")

    def __call__(self, points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        names = {"x": points[:, 0], "y": points[:, 1], **_CONSTANTS}
        with np.errstate(all="ignore"):
            value = self._evaluate(self._tree, names)
        return np.broadcast_to(np.asarray(value, dtype=float), (len(points),)).copy()

    def _evaluate(self, node: ast.AST, names: dict):
        if isinstance(node, ast.Constant):
            return float(node.value)
        if isinstance(node, ast.Name):
            return names[node.id]
        if isinstance(node, ast.BinOp):
            left, right = self._evaluate(node.left, names), self._evaluate(node.right, names)
            return _BINARY[type(node.op)](np.asarray(left, dtype=float), right)
        if isinstance(node, ast.UnaryOp):
            return _UNARY[type(node.op)](self._evaluate(node.operand, names))
        return FUNCTIONS[node.func.id](self._evaluate(node.args[0], names))

    def __repr__(self) -> str:
        return f"Expression({self.text!r})"
