"""Print pip's package sources as ``uv pip install`` flags, one per line.

uv does not read pip's configuration; the set-up installs with uv (much faster than pip) and must look where pip
looks on this machine: its indexes, its local wheel folders and its constraints, from ``pip config list`` (pip's
files and its PIP_* environment variables alike). A key set in the environment wins over the files, as in pip.
"""

from __future__ import annotations

import ast
import subprocess
import sys

FLAGS = {"index-url": "--index-url", "extra-index-url": "--extra-index-url", "find-links": "--find-links",
         "constraint": "--constraint"}


def pip_settings(lines) -> dict:
    """``{key: [values]}`` of the keys uv needs, from ``pip config list``'s lines; the environment's win."""
    found, from_env = {}, set()
    for line in lines:
        name, sep, value = line.partition("=")
        key = name.rsplit(".", 1)[-1]
        if not sep or key not in FLAGS or (key in from_env and not name.startswith(":env:")):
            continue
        try:
            value = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            continue
        found[key] = str(value).split()
        if name.startswith(":env:"):
            from_env.add(key)
    return found


def main() -> None:
    """Print the flags for the pip of the Python running this."""
    out = subprocess.run([sys.executable, "-m", "pip", "config", "list"], capture_output=True, text=True).stdout
    for key, values in pip_settings(out.splitlines()).items():
        for value in values:
            print(f"{FLAGS[key]}={value}")


if __name__ == "__main__":
    main()
