"""Loading validated YAML configs with errors that name the file, the field and the expected value.

All simnav configs are frozen pydantic models whose defaults are the product; YAML files override only what
differs, and ``--set a.b=c`` overrides single fields from the command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from simnav.errors import ConfigError

ModelT = TypeVar("ModelT", bound=BaseModel)


class FrozenModel(BaseModel):
    """Base of every simnav config: immutable, unknown fields rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid")


def check_whole_multiples(model: BaseModel, names: tuple[str, ...], base: str) -> None:
    """Raise ValueError unless every field in ``names`` is a whole multiple (>= 1) of the field ``base``
    (e.g. control and agent periods of the physics step)."""
    base_value = getattr(model, base)
    for name in names:
        ratio = getattr(model, name) / base_value
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ValueError(f"{name}={getattr(model, name)} must be a whole multiple of {base}={base_value}")


def format_validation_error(err: ValidationError, source: str) -> str:
    """One readable message per failing field: ``source: field.path: message (got value)``."""
    lines = []
    for item in err.errors():
        loc = ".".join(str(p) for p in item["loc"])
        msg = item["msg"].removeprefix("Value error, ")  # raised by a validator: its message says it all
        got = item.get("input")
        got_txt = "" if isinstance(got, dict | list) or got is None or repr(got) in msg else f" (got {got!r})"
        lines.append(f"{source}: field '{loc}': {msg}{got_txt}" if loc else f"{source}: {msg}")
    return "\n".join(lines)


def validate(model: type[ModelT], data: Any, source: str) -> ModelT:
    """Validate ``data`` into ``model``; raise :class:`ConfigError` naming ``source`` and the fields."""
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise ConfigError(format_validation_error(err, source)) from None


def read_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping; malformed YAML or a non-mapping top level raise :class:`ConfigError`."""
    try:
        text = path.read_text()
    except OSError as err:
        raise ConfigError(f"{path}: cannot read file ({err.strerror})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(err, "problem", None) or str(err)
        raise ConfigError(f"{path}: malformed YAML{where}: {problem}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a YAML mapping at the top level, got {type(data).__name__}")
    return data


def apply_overrides(data: dict[str, Any], overrides: list[str] | None, source: str = "--set") -> dict[str, Any]:
    """Apply dotted ``key.sub=value`` overrides (values parsed as YAML scalars) to a nested dict copy.

    A path step into a list is an index (``sensors.1.rate_hz=15``) or the ``name`` of an item
    (``sensors.camera.rate_hz=15``).
    """
    result = _deep_copy(data)
    for item in overrides or []:
        if "=" not in item:
            raise ConfigError(f"{source}: expected KEY=VALUE (e.g. drive.max_v_m_s=0.4), got {item!r}")
        key, raw = item.split("=", 1)
        parts = [p for p in key.strip().split(".") if p]
        if not parts:
            raise ConfigError(f"{source}: empty key in {item!r}")
        node: Any = result
        for part in parts[:-1]:
            node = _child(node, part, key, source, create=True)
        _assign(node, parts[-1], yaml.safe_load(raw), key, source)
    return result


def _child(node: Any, part: str, key: str, source: str, create: bool) -> Any:
    if isinstance(node, dict):
        return node.setdefault(part, {}) if create else node[part]
    if isinstance(node, list):
        return node[_list_index(node, part, key, source)]
    raise ConfigError(f"{source}: '{key}' goes through '{part}', which is not a mapping or a list")


def _assign(node: Any, part: str, value: Any, key: str, source: str) -> None:
    if isinstance(node, dict):
        node[part] = value
    elif isinstance(node, list):
        node[_list_index(node, part, key, source)] = value
    else:
        raise ConfigError(f"{source}: cannot set '{key}': its parent is not a mapping or a list")


def _list_index(items: list, part: str, key: str, source: str) -> int:
    if part.lstrip("-").isdigit() and -len(items) <= int(part) < len(items):
        return int(part)
    names = [it.get("name") for it in items if isinstance(it, dict)]
    if part in names:
        return names.index(part)
    raise ConfigError(f"{source}: '{key}': no list item '{part}' (indices 0..{len(items) - 1}"
                      + (f", names {names})" if any(names) else ")"))


def _deep_copy(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _deep_copy(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_deep_copy(v) for v in data]
    return data


def load_named(kind: str, model: type[ModelT], name_or_path: str | Path, overrides: list[str] | None) -> ModelT:
    """Load a shipped ``kind`` file (``robots``, ``worlds``) by name or a YAML path, apply overrides, validate.

    The ``name`` field defaults to the file's stem.
    """
    from simnav import assets

    path = assets.resolve(kind, name_or_path)
    data = apply_overrides(read_yaml(path), overrides)
    data.setdefault("name", path.stem)
    return validate(model, data, str(path))


def dump_yaml(model: BaseModel) -> str:
    """The resolved config as YAML (stable key order, for reproducible run folders)."""
    return yaml.safe_dump(model.model_dump(mode="json"), sort_keys=False)
