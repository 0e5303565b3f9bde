"""The field kinds as a typed choice, defined once, without importing torch (the CLI's ``--field``)."""

from __future__ import annotations

from typing import Literal, get_args

#: the field kinds (``train --field``); each has one ``FIELD_REGISTRY`` entry (tests/test_fields.py)
FieldKind = Literal["grid", "mlp"]
FIELD_KINDS: tuple[str, ...] = get_args(FieldKind)
