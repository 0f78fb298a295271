#!/usr/bin/env bash
# Fresh-machine set-up for drem-maniskill; `make demo` and `make test` run it
# first, so it must be cheap when nothing changed.
#
#   1. a virtualenv at .venv (created with the system's python3, reused after)
#   2. the package, `-e ".[test,sweep]"`, installed into it with uv (pip where uv cannot) --
#      skipped while pyproject.toml is unchanged since the last successful install
#      (sha256 kept in a stamp)
#   3. a Vulkan device for SAPIEN (scripts/ensure_vulkan.sh)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

VENV="$ROOT/.venv"
PY="$VENV/bin/python"
STAMP="$VENV/.drem-installed"

say() { echo "[setup] $*"; }

# 1. venv.  A venv whose interpreter no longer starts (e.g. the system Python
#    it was made from was replaced) is rebuilt rather than patched.
if [ -x "$PY" ] && "$PY" -c "" 2>/dev/null; then
    say "reusing virtualenv $VENV"
else
    if [ -e "$VENV" ]; then
        say "virtualenv $VENV is broken; recreating it"
        rm -rf "$VENV"
    fi
    command -v python3 >/dev/null ||
        { echo "[setup] ERROR: python3 not found; install Python >= 3.9 (Debian: apt-get install python3 python3-venv)" >&2; exit 1; }
    say "creating virtualenv $VENV with $(python3 --version)"
    python3 -m venv "$VENV" ||
        { echo "[setup] ERROR: 'python3 -m venv' failed; on Debian/Ubuntu: apt-get install python3-venv" >&2; exit 1; }
fi

# Everything here runs on the CPU. Where a CPU-only torch build is at hand (these machines keep
# torch 2.13.0+cpu locally), take it first so that the installer does not pull gigabytes of CUDA
# wheels for the newest torch; elsewhere it chooses a torch in pyproject's range.
TORCH="torch==2.13.0"

# uv installs the same packages as pip in a fraction of the time (measured here: 35 s against
# 2 min for a new venv); it reads pip's sources through scripts/uv_args.py.
install_with_uv() {
    "$PY" -m pip install --quiet uv >/dev/null 2>&1 || return 1
    local args
    args="$("$PY" "$ROOT/scripts/uv_args.py")" || return 1
    # pip's resolution: the best version across every index, not the first index that has the package.
    local uv=("$VENV/bin/uv" pip install --python "$PY" --index-strategy unsafe-best-match)
    while IFS= read -r a; do [ -n "$a" ] && uv+=("$a"); done <<<"$args"
    if ! "$PY" -c "import torch" 2>/dev/null; then
        "${uv[@]}" "$TORCH" -e ".[test,sweep]" && return 0
        say "$TORCH not available here; uv chooses a torch in pyproject's range"
    fi
    "${uv[@]}" -e ".[test,sweep]"
}

install_with_pip() {
    if ! "$PY" -c "import torch" 2>/dev/null; then
        "$PY" -m pip install "$TORCH" 2>/dev/null ||
            say "$TORCH not available here; pip will choose a torch in pyproject's range"
    fi
    "$PY" -m pip install -e ".[test,sweep]"
}

# 2. The package, editable, with the test and sweep (Ray) extras.  The
#    stamp holds the sha256 of pyproject.toml and is written only after the
#    install succeeded, so an interrupted install is retried next time.  We also
#    check that the distribution is really there, in case someone
#    pip-uninstalled it.
WANT="$(sha256sum pyproject.toml | cut -d' ' -f1)"
HAVE="$(cat "$STAMP" 2>/dev/null || true)"
if [ "$WANT" = "$HAVE" ] && [ -x "$VENV/bin/drem-maniskill" ] &&
    "$PY" -c 'import importlib.metadata as m; m.version("drem-maniskill")' 2>/dev/null; then
    say "package already installed and pyproject.toml unchanged; skipping the install"
else
    say "installing -e \".[test,sweep]\" (first time or pyproject.toml changed) ..."
    rm -f "$STAMP"
    if ! install_with_uv; then
        say "uv could not install here; pip does it (takes a few minutes) ..."
        install_with_pip
    fi
    echo "$WANT" >"$STAMP"
fi

# 3. Vulkan for SAPIEN.
bash "$ROOT/scripts/ensure_vulkan.sh"
say "done"
