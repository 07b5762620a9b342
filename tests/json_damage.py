"""Damage to a JSON record at any of its fields, for the property-based tests of readers (the returned records of a
GPU allocation, an exported model folder)."""


def paths_of(obj, prefix=()):
    """Every key path into a JSON value (the value itself first)."""
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from paths_of(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from paths_of(v, (*prefix, i))


def replaced(obj, path, value):
    """``obj`` with the value at key path ``path`` replaced by ``value`` (in place; the value itself when empty)."""
    if not path:
        return value
    obj[path[0]] = replaced(obj[path[0]], path[1:], value)
    return obj
