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
    """``yaml.SafeLoader`` refusing a mapping that repeats a key."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # ``<<: *base``: its keys may be overridden here
                continue
            key = self.construct_object(key_node, deep=deep)
            try:
                repeated = key in seen
                seen.add(key)
            except TypeError:  # an unhashable key: the base class says what is wrong with it
                break
            if repeated:  # (the line in the words: the error's own mark adds four lines of context)
                line = key_node.start_mark.line + 1
                raise yaml.constructor.ConstructorError(
                    problem=f"duplicate key {key!r} at line {line} (given twice: which one is meant?)"
                )
        return super().construct_mapping(node, deep=deep)


def load_yaml(text: str) -> Any:
    """``yaml.safe_load(text)``, but a mapping that repeats a key raises ``yaml.YAMLError`` (the key and the
    line of its second use in the message)."""
    return yaml.load(text, Loader=_UniqueKeyLoader)
