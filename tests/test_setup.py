"""The set-up's uv install looks where pip looks."""

from __future__ import annotations

import runpy
from pathlib import Path

UV_ARGS = runpy.run_path(str(Path(__file__).resolve().parents[1] / "scripts" / "uv_args.py"))


def test_pips_sources_become_uv_flags_and_the_environment_wins_over_the_files():
    lines = [
        ":env:.find-links='/opt/wheels'",
        ":env:.default-timeout='180'",
        "global.find-links='/somewhere/else'",
        "global.extra-index-url='file:///a/simple file:///b/simple'",
        "global.constraint='/etc/caps.txt'",
        "user.cert='/etc/ssl/certs/ca.crt'",
        "not a setting",
    ]
    settings = UV_ARGS["pip_settings"](lines)
    assert settings == {"find-links": ["/opt/wheels"], "extra-index-url": ["file:///a/simple", "file:///b/simple"],
                        "constraint": ["/etc/caps.txt"]}
    # A file read after the environment does not override it either.
    assert UV_ARGS["pip_settings"](list(reversed(lines)))["find-links"] == ["/opt/wheels"]
