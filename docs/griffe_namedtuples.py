"""Griffe extension: a ``typing.NamedTuple`` class gets the constructor Python generates for it.

Griffe reads the source statically and models dataclasses' generated ``__init__`` but not a NamedTuple's, so
its fields, documented as ``:param:`` in SB3's style, would match no parameter.
"""

from __future__ import annotations

from typing import Any

from griffe import Attribute, Class, Extension, Function, Parameter, ParameterKind, Parameters


class NamedTupleFields(Extension):
    """Give each NamedTuple class without an ``__init__`` one whose parameters are its annotated fields."""

    def on_class(self, *, cls: Class, **kwargs: Any) -> None:
        if "__init__" in cls.members or not any(str(base).endswith("NamedTuple") for base in cls.bases):
            return
        fields = [
            Parameter(
                name=member.name,
                annotation=member.annotation,
                kind=ParameterKind.positional_or_keyword,
                default=member.value,
            )
            for member in cls.members.values()
            if isinstance(member, Attribute) and member.annotation is not None
        ]
        init = Function("__init__", lineno=0, endlineno=0, parent=cls, parameters=Parameters(*fields), returns="None")
        cls.set_member("__init__", init)
