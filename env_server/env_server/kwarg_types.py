"""Refuse, at Make, a keyword argument whose value cannot have its parameter's type.

A constructor that stores `step_size="big"` fails on its first step, or raises from
inside NumPy, far from the request that caused it; checked against the parameter's
default before anything is built, the error names the keyword. Only plain scalar
defaults (bool, int, float, str) are checked: annotations may be strings (PEP 563)
and None, tuples or callables say nothing about what else a parameter accepts.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

from env_server.errors import InvalidArgument, quote


def check_kwarg_types(env_id: str, params: Mapping[str, inspect.Parameter], kwargs: Mapping[str, Any]) -> None:
    """InvalidArgument naming the first keyword whose value does not fit its parameter's default."""
    for name, value in kwargs.items():
        param = params.get(name)
        default = param.default if param is not None else inspect.Parameter.empty
        if isinstance(default, bool):
            ok, want = isinstance(value, bool), "a boolean"
        elif isinstance(default, (int, float)):
            # JSON has one number type: 1 is a fine float, 1.5 is no int.
            allowed = int if isinstance(default, int) else (int, float)
            ok, want = isinstance(value, allowed) and not isinstance(value, bool), f"a {type(default).__name__}"
        elif isinstance(default, str):
            ok, want = isinstance(value, str), "a string"
        else:
            continue
        if not ok:
            raise InvalidArgument(
                f"kwargs_json: env '{env_id}' keyword '{name}' expects {want} (its default is {default!r}), got {quote(value)}"
            )
