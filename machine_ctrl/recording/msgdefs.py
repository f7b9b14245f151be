"""ROS 2 message definitions from the ament index, for bag schemas (no rclpy import).

A message type is named ``pkg/msg/Type`` (the form rosbag2 and rclpy use; ``pkg/Type`` is
accepted too). Its definition is ``<prefix>/share/<pkg>/msg/<Type>.msg`` of the first prefix
on AMENT_PREFIX_PATH that registers ``pkg`` in the ament index. The ``ros2msg`` schema of a
type (MCAP ros2 profile) is its .msg text followed, for every nested type it depends on
(depth first, each once), by a line of 80 ``=``, a line ``MSG: pkg/Type`` and that type's
.msg text. The REP-2011 type hash (``RIHS01_...``) comes from the ``<Type>.json`` type
description that rosidl installs beside the .msg.
"""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

SEPARATOR = '=' * 80
PRIMITIVES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                        'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'})
_TYPE_NAME = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z][A-Za-z0-9_]*)$')


class DefinitionNotFound(LookupError):
    """A message type whose definition is not installed (the text says which and where)."""


def split_type(type_name: str) -> tuple[str, str]:
    """('pkg', 'Type') of 'pkg/msg/Type' or 'pkg/Type'; ValueError for anything else."""
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise ValueError(f'{type_name!r} is not a message type name (pkg/msg/Type)')
    return match.group(1), match.group(2)


def full_name(type_name: str) -> str:
    """'pkg/msg/Type' for 'pkg/Type' or 'pkg/msg/Type'."""
    package, name = split_type(type_name)
    return f'{package}/msg/{name}'


def _prefixes() -> list[Path]:
    return [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]


def _msg_dir(package: str) -> Path:
    for prefix in _prefixes():
        if (prefix / 'share/ament_index/resource_index/packages' / package).is_file():
            return prefix / 'share' / package / 'msg'
    raise DefinitionNotFound(f'package {package!r} is not in the ament index '
                             f'(AMENT_PREFIX_PATH={os.environ.get("AMENT_PREFIX_PATH", "")!r})')


def _read(package: str, name: str, suffix: str) -> str:
    path = _msg_dir(package) / f'{name}{suffix}'
    try:
        return path.read_text(encoding='utf-8')
    except OSError:
        raise DefinitionNotFound(f'no definition of {package}/msg/{name} ({path})') from None


def message_text(type_name: str) -> str:
    """The installed .msg text of one type."""
    return _read(*split_type(type_name), '.msg')


def dependencies(text: str, package: str) -> list[str]:
    """Nested message types ('pkg/Type') of a .msg text, in field order, each once. A field
    line is ``TYPE NAME`` (constants ``TYPE NAME=VALUE``); TYPE may carry an array suffix
    ``[...]`` or a string bound ``<=N``; a type without a package is of the same package."""
    found = []
    for line in text.splitlines():
        fields = line.split('#', 1)[0].split()
        if len(fields) < 2:
            continue
        base = re.split(r'[\[<]', fields[0], maxsplit=1)[0]
        if base in PRIMITIVES:
            continue
        name = base if '/' in base else f'{package}/{base}'
        if name not in found:
            found.append(name)
    return found


def definition(type_name: str) -> str:
    """The ros2msg schema text of `type_name`: its .msg and those of all its dependencies."""
    package, _ = split_type(type_name)
    text = message_text(type_name)
    seen: set[str] = set()
    parts = [text]

    def append(deps: list[str]) -> None:
        for dep in deps:
            key = '/'.join(split_type(dep))
            if key in seen:
                continue
            seen.add(key)
            dep_text = message_text(dep)
            parts.append(f'{SEPARATOR}\nMSG: {key}\n{dep_text}')
            append(dependencies(dep_text, split_type(dep)[0]))

    append(dependencies(text, package))
    return '\n'.join(parts)


def type_hash(type_name: str) -> str:
    """REP-2011 hash 'RIHS01_<hex>' of `type_name`, or '' when no type description is
    installed (older distributions)."""
    package, name = split_type(type_name)
    try:
        description = json.loads(_read(package, name, '.json'))
    except (DefinitionNotFound, ValueError):
        return ''
    wanted = f'{package}/msg/{name}'
    for entry in description.get('type_hashes', []):
        if entry.get('type_name') == wanted:
            return str(entry.get('hash_string', ''))
    return ''
