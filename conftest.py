"""Doctest collection skips the modules whose optional extra is not installed.

``make test`` installs every extra; this lets ``pytest`` run in an environment with only some.
"""

import importlib.util

_OPTIONAL = {
    "stonesoup": ["hocnet/tracking/stonesoup.py"],
    "lightning": ["hocnet/learn"],
    "ray": ["hocnet/sweep.py"],
}

collect_ignore = [
    path
    for package, paths in _OPTIONAL.items()
    if importlib.util.find_spec(package) is None
    for path in paths
]
