"""Safe YAML whose every failure is a ``yaml.YAMLError`` with a line: PyYAML's own safe
loader turns an integer of more than 4300 decimal digits (Python's limit on converting
text to ``int``) into a bare ``ValueError``, which callers that handle bad YAML do not
expect. Here it is a ``ConstructorError`` at the number's line."""

from __future__ import annotations

from typing import Any

import yaml

INT_TAG = "tag:yaml.org,2002:int"
MAX_INT_DIGITS = 4300  # sys.get_int_max_str_digits() by default


class SafeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses an integer too long to convert, at its line."""


def _construct_int(loader: yaml.SafeLoader, node: yaml.ScalarNode) -> Any:
    try:
        return yaml.SafeLoader.construct_yaml_int(loader, node)
    except ValueError:
        raise yaml.constructor.ConstructorError(
            None, None, f"a number of more than {MAX_INT_DIGITS} digits", node.start_mark
        ) from None


SafeLoader.add_constructor(INT_TAG, _construct_int)

_C_LOADER: type = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class FastSafeLoader(_C_LOADER):  # type: ignore[misc, valid-type]
    """:class:`SafeLoader`'s check on libyaml's parser (PyYAML's C one where installed)."""


FastSafeLoader.add_constructor(INT_TAG, _construct_int)


def safe_load(text: str) -> Any:
    """``yaml.safe_load(text)`` with :class:`SafeLoader`."""
    loader = SafeLoader(text)
    try:
        return loader.get_single_data()
    finally:
        loader.dispose()
