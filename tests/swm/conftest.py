"""The stable-worldmodel bridge's tests run against the real package (``pip install -e ".[swm,test]"``, an
environment of its own: docs/stable_worldmodel.md); without it they are not collected, so the core suite stays
lean and ``pytest tests/swm`` in the core environment reports nothing to run instead of failing."""

import importlib.util

collect_ignore_glob = [] if importlib.util.find_spec("stable_worldmodel") else ["*.py"]
