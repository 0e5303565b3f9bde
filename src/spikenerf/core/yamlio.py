"""YAML that a user wrote, read strictly: a key given twice is an error, not the last value silently.

PyYAML's ``safe_load`` keeps the last of two equal keys, so a ``config.yaml`` with ``spike_h: 32`` and
later ``spike_h: 16`` (an edit that left the old line) read as 16 without a word. :func:`load_yaml` is
``safe_load`` with that refused as a ``yaml.YAMLError`` naming the key and its line, so that the callers'
handlers of malformed YAML report it in their one line.
"""

from __future__ import annotations

from typing import Any

import yaml


class _UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` refusing a mapping that repeats a key.

    Each mapping node is checked once, as written, before its merge keys (``<<: *base``) are flattened
    into it: a key of its own may override a merged one, and a node flattened in place (an anchor inside a
    merge) is not checked again with the merged keys."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._checked: set[int] = set()

    def flatten_mapping(self, node: yaml.MappingNode) -> None:
        if id(node) not in self._checked:
            self._checked.add(id(node))
            self._refuse_repeated(node)
        super().flatten_mapping(node)

    def _refuse_repeated(self, node: yaml.MappingNode) -> None:
        seen: set = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node)
            try:
                repeated = key in seen
                seen.add(key)
            except TypeError:  # an unhashable key: the base class says what is wrong with it
                return
            if repeated:  # (the line in the words: the error's own mark adds four lines of context)
                line = key_node.start_mark.line + 1
                raise yaml.constructor.ConstructorError(
                    problem=f"duplicate key {key!r} at line {line} (given twice: which one is meant?)"
                )


def load_yaml(text: str) -> Any:
    """``yaml.safe_load(text)``, but a mapping that repeats a key raises ``yaml.YAMLError`` (the key and the
    line of its second use in the message), and so do what PyYAML raises as other types: a structure nested
    beyond Python's stack (RecursionError), an integer beyond Python's digit limit or an impossible date
    (ValueError)."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except RecursionError:
        raise yaml.YAMLError("nested too deeply to read") from None
    except ValueError as err:  # (``int()`` of 5000 digits, ``2020-13-01`` read as a date)
        raise yaml.YAMLError(f"unreadable value: {err}") from None
