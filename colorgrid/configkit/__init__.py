"""The config toolkit: one way to validate, build, override and expose frozen dataclass configs.

Every config of the project (``EnvConfig``, the training configs, ``BayesConfig``, ``ServerSettings``) is a frozen
dataclass with a docstring per field, validated in ``__post_init__`` with the checks of ``checks`` (each naming the
field, the value and what is allowed, in the style its ``ConfigBase`` hooks declare), built from plain data by
``from_dict`` (nested dataclasses included), changed with ``KEY=VALUE`` overrides (``split_override``,
``apply_overrides``), named in presets (``Presets``: the training presets; the env's are ``colorgrid.presets``), and
turned into command-line flags by ``cli`` (``add_arguments``, ``from_args``). ``resolve`` is the one way a config is
resolved from a preset, a file and overrides.

- ``checks``: ``ConfigError``, ``ConfigBase`` (the error-style hooks) and the field checks;
- ``build``: ``from_dict``, ``to_dict``, ``read_toml``, overrides, ``resolve``, ``Presets``;
- ``cli``: ``Flag``, ``add_arguments``, ``from_args``, ``field_docs``.
"""

from colorgrid.configkit.build import (Presets, apply_overrides, from_dict, keys_named, merge, override_dict,
                                       read_toml, resolve, resolve_data, split_override, to_dict)
from colorgrid.configkit.checks import (FIELD_FIRST, UNKNOWN_FIELDS, ConfigBase, ConfigError, check_bool,
                                        check_choice, check_int, check_member, check_number, check_strings, fail,
                                        hooks, is_int, is_number)
from colorgrid.configkit.cli import Flag, add_arguments, field_docs, from_args

__all__ = ["FIELD_FIRST", "UNKNOWN_FIELDS", "ConfigBase", "ConfigError", "Flag", "Presets", "add_arguments",
           "apply_overrides", "check_bool", "check_choice", "check_int", "check_member", "check_number",
           "check_strings", "field_docs", "fail", "from_args", "from_dict", "hooks", "is_int", "is_number",
           "keys_named", "merge", "override_dict", "read_toml", "resolve", "resolve_data", "split_override", "to_dict"]
