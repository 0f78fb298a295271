#!/usr/bin/env bash
# Make sure SAPIEN (ManiSkill's simulator/renderer) can get a Vulkan device.
#
# Every ManiSkill environment builds a SAPIEN render system, even with
# state-only observations, so without a Vulkan device nothing runs.  Our
# machines have no GPU: SAPIEN then renders on the CPU through Mesa's
# "lavapipe" Vulkan driver.  Debian bookworm's own Mesa (22.3) is too old --
# SAPIEN fails with "failed to find a rendering device" -- while the Mesa in
# bookworm-backports (>= 24.3) works.
#
# What this script does:
#   1. Probe: render one small image with SAPIEN.  If that works, stop here
#      (so a second run costs about a second and changes nothing).
#   2. Otherwise, on Debian as root: add <codename>-backports as an apt
#      source, derived at run time from the machine's existing Debian source
#      (same mirror, same keyring), install Mesa's Vulkan drivers from it,
#      check the version, and probe again.
#   3. Anywhere else: explain what to install and exit non-zero.
#
# Usage: scripts/ensure_vulkan.sh            (uses .venv/bin/python)
#        PYTHON=/path/to/python scripts/ensure_vulkan.sh
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PYTHON="${PYTHON:-$ROOT/.venv/bin/python}"
MIN_MESA="24.3"                      # first Mesa whose lavapipe SAPIEN accepts
SOURCE_FILE="/etc/apt/sources.list.d/drem-backports.sources"
PACKAGES="mesa-vulkan-drivers libvulkan1"

say() { echo "[ensure_vulkan] $*"; }
die() {
    echo "[ensure_vulkan] ERROR: $*" >&2
    exit 1
}

[ -x "$PYTHON" ] || die "no Python at $PYTHON; run scripts/setup.sh first (it creates .venv)."

PROBE_LOG="$(mktemp)"
trap 'rm -f "$PROBE_LOG"' EXIT
# Remembers the last full probe that passed (see probe below); lives in the
# venv, next to the SAPIEN it vouches for.
PROBE_STAMP="$(dirname "$PYTHON")/../.drem-vulkan-ok"

# The honest test is to render a picture: a 32x32 image of a ground plane,
# checking that the plane shows up where it should.  On lavapipe that costs about
# a second (shader compilation), more than is worth repeating on every `make test`.  So the probe
# first just creates SAPIEN's RenderSystem (~0.5 s; this is the step that
# fails with "failed to find a rendering device" when there is no usable
# device), and renders only if the device, SAPIEN or the installed Vulkan
# drivers changed since the last full probe passed.  FULL=1 forces the render.
# A timeout guards against a driver that hangs instead of failing.
probe() {
    FULL="${FULL:-0}" timeout 300 "$PYTHON" - "$PROBE_STAMP" >"$PROBE_LOG" 2>&1 <<'EOF'
import glob, os, sys, warnings
warnings.simplefilter("ignore")  # "Fallback to SAPIEN builtin libvulkan" is noise here
try:
    import sapien
except ImportError as e:
    print("cannot import sapien: %s" % e)
    sys.exit(3)                      # not a Vulkan problem; see below

stamp = sys.argv[1]
render_system = sapien.render.RenderSystem()   # raises if there is no device
summary = sapien.render.get_device_summary()
devices = ", ".join(l.split(":", 1)[1].strip() for l in summary.splitlines() if l[:1] not in " \t" and ":" in l)

# What the verdict depends on: SAPIEN, the devices it sees, the Vulkan driver
# manifests (rewritten by every driver upgrade) and the env vars choosing them.
icds = sorted(glob.glob("/usr/share/vulkan/icd.d/*.json") + glob.glob("/etc/vulkan/icd.d/*.json"))
key = "\n".join([sapien.__version__, summary]
                + ["%s %d" % (f, os.stat(f).st_mtime) for f in icds]
                + ["%s=%s" % (v, os.environ.get(v, "")) for v in ("VK_ICD_FILENAMES", "VK_DRIVER_FILES")])
try:
    cached = open(stamp).read() == key
except OSError:
    cached = False
if cached and os.environ.get("FULL") != "1":
    print("Vulkan device %s (rendered fine before; nothing changed since)" % devices)
    sys.exit(0)

import numpy as np
scene = sapien.Scene([sapien.physx.PhysxCpuSystem(), render_system])
scene.set_ambient_light([0.6, 0.6, 0.6])
scene.add_ground(altitude=-1.0)      # camera looks along +x; ground fills the lower half
camera = scene.add_camera("probe", 32, 32, 1.0, 0.01, 10.0)
# No environment map: a blank BRDF table draws the same picture without SAPIEN computing its own
# (about 12 s of CPU on lavapipe; drem_maniskill/envs/rendering.py).
camera.set_texture("BRDFLUT", sapien.render.RenderTexture(np.zeros((1, 1, 4), np.float32), 2, "R32G32B32A32Sfloat"))
scene.update_render()
camera.take_picture()
rgba = np.asarray(camera.get_picture("Color"))
assert rgba.shape == (32, 32, 4) and np.isfinite(rgba).all(), "bad color image"
# Check the geometry really was rasterized: the bottom row sees the ground
# (camera-space z < 0), the top row sees only sky (z == 0, nothing drawn).
z = np.asarray(camera.get_picture("Position"))[..., 2]
assert (z[-1] < 0).all() and (z[0] == 0).all(), "the ground plane was not drawn"
with open(stamp, "w") as f:
    f.write(key)
print("rendered a 32x32 image on Vulkan device %s" % devices)
EOF
}

say "probing SAPIEN for a Vulkan render device ..."
rc=0
probe || rc=$?
if [ "$rc" = 0 ]; then
    say "OK: $(tail -n 1 "$PROBE_LOG")"
    exit 0
fi
rm -f "$PROBE_STAMP"
[ "$rc" != 3 ] || die "$(cat "$PROBE_LOG") -- $PYTHON lacks SAPIEN; run scripts/setup.sh (it pip-installs the package)."
say "probe failed:"
sed 's/^/    /' "$PROBE_LOG" | tail -n 8

# ---------------------------------------------------------------------------
# No device.  From here on we can only help on Debian, as root.
# ---------------------------------------------------------------------------
manual_fix() {
    cat >&2 <<EOF

[ensure_vulkan] SAPIEN found no Vulkan device, and this script can only install
one on Debian as root.  To fix it by hand:
  * with an NVIDIA GPU: install the NVIDIA driver including its Vulkan ICD
    (/usr/share/vulkan/icd.d/nvidia_icd.json).
  * without a GPU: install Mesa's CPU Vulkan driver (lavapipe) version
    >= $MIN_MESA plus the Vulkan loader ($PACKAGES).  On Debian 12 as root:
    add 'bookworm-backports' to your apt sources, then
      apt-get update && apt-get install -t bookworm-backports $PACKAGES
    Distributions that ship Mesa >= $MIN_MESA (e.g. Debian 13, Ubuntu 25.04)
    need only: apt-get install $PACKAGES
Then re-run: bash scripts/ensure_vulkan.sh
EOF
    exit 1
}

# shellcheck disable=SC1091  # os-release is a plain KEY=value file
[ -r /etc/os-release ] && . /etc/os-release
if [ "${ID:-}" != "debian" ] || [ -z "${VERSION_CODENAME:-}" ]; then
    say "this is not Debian (ID=${ID:-unknown})."
    manual_fix
fi
if [ "$(id -u)" != "0" ]; then
    say "not running as root, so apt-get cannot be used."
    manual_fix
fi
CODENAME="$VERSION_CODENAME"
BACKPORTS="$CODENAME-backports"
export DEBIAN_FRONTEND=noninteractive
APT_OPTS=(-y -o DPkg::Lock::Timeout=600)   # wait for, rather than fail on, a concurrent apt

installed_mesa() { dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true; }

# Is there any known (installable) mesa-vulkan-drivers >= MIN_MESA?
candidate_known() {
    local v
    for v in $(apt-cache madison mesa-vulkan-drivers 2>/dev/null | awk -F'|' '{gsub(/ /, "", $2); print $2}'); do
        dpkg --compare-versions "$v" ge "$MIN_MESA" && return 0
    done
    return 1
}

# Print a deb822 source for <codename>-backports, built from the machine's
# existing apt source for the plain release <codename>: same URI(s), same
# components, same Signed-By.  Understands both the deb822 *.sources format
# and the classic one-line sources.list format.  Prints nothing if some
# source already provides <codename>-backports (other than our own file).
derive_backports_source() {
    python3 - "$CODENAME" "$SOURCE_FILE" <<'EOF'
import glob, os, re, sys

codename, own_file = sys.argv[1], sys.argv[2]
backports = codename + "-backports"
entries = []  # dicts with: file, uris (list), suites (list), components (list), signed_by (str or None)

def parse_deb822(path):
    text = open(path, encoding="utf-8", errors="replace").read()
    for stanza in re.split(r"\n\s*\n", text):
        fields, key = {}, None
        for line in stanza.splitlines():
            if line.startswith("#"):
                continue
            if line[:1] in (" ", "\t") and key:          # continuation line (e.g. inline key)
                fields[key] += "\n" + line
            elif ":" in line:
                key, value = line.split(":", 1)
                key = key.strip().lower()
                fields[key] = value.strip()
        if "deb" not in fields.get("types", "").split():
            continue
        if fields.get("enabled", "yes").strip().lower() == "no":
            continue
        entries.append(dict(file=path, uris=fields.get("uris", "").split(),
                            suites=fields.get("suites", "").split(),
                            components=fields.get("components", "").split(),
                            signed_by=fields.get("signed-by")))

def parse_one_line(path):
    for line in open(path, encoding="utf-8", errors="replace"):
        line = line.split("#", 1)[0].strip()
        m = re.match(r"^deb\s+(?:\[([^\]]*)\]\s+)?(\S+)\s+(\S+)\s*(.*)$", line)
        if not m:
            continue                                      # blank, comment or deb-src
        options = dict(o.split("=", 1) for o in (m.group(1) or "").split() if "=" in o)
        entries.append(dict(file=path, uris=[m.group(2)], suites=[m.group(3)],
                            components=m.group(4).split(), signed_by=options.get("signed-by")))

if os.path.exists("/etc/apt/sources.list"):
    parse_one_line("/etc/apt/sources.list")
for path in sorted(glob.glob("/etc/apt/sources.list.d/*.list")):
    parse_one_line(path)
for path in sorted(glob.glob("/etc/apt/sources.list.d/*.sources")):
    parse_deb822(path)

if any(backports in e["suites"] for e in entries if e["file"] != own_file):
    sys.exit(0)                                           # already configured by someone else

base = [e for e in entries if codename in e["suites"] and e["uris"] and e["file"] != own_file]
base.sort(key=lambda e: "main" not in e["components"])   # prefer the entry that has 'main'
if not base:
    sys.exit("no enabled apt source for suite '%s' found in /etc/apt" % codename)
e = base[0]
print("# Written by drem-maniskill's scripts/ensure_vulkan.sh: newer Mesa (lavapipe)")
print("# for SAPIEN. Derived from the '%s' entry in %s." % (codename, e["file"]))
print("Types: deb")
print("URIs: " + " ".join(e["uris"]))
print("Suites: " + backports)
print("Components: " + (" ".join(e["components"]) or "main"))
if e["signed_by"]:
    print("Signed-By: " + e["signed_by"])
EOF
}

# 1. An apt source for backports (only rewritten when its content changes).
NEW_SOURCE="$(derive_backports_source)" || die "could not derive a $BACKPORTS apt source from /etc/apt (see message above)."
if [ -z "$NEW_SOURCE" ]; then
    say "apt already has a $BACKPORTS source; using it."
elif [ -f "$SOURCE_FILE" ] && [ "$(cat "$SOURCE_FILE")" = "$NEW_SOURCE" ]; then
    say "apt source $SOURCE_FILE is already in place."
else
    say "writing apt source $SOURCE_FILE:"
    printf '%s\n' "$NEW_SOURCE" | sed 's/^/    /'
    printf '%s\n' "$NEW_SOURCE" >"$SOURCE_FILE"
fi

# 2. Refresh package lists only when apt does not yet know a new enough Mesa.
if candidate_known; then
    say "apt already knows mesa-vulkan-drivers >= $MIN_MESA; skipping apt-get update."
else
    say "apt-get update ..."
    apt-get "${APT_OPTS[@]}" -q update
    candidate_known || die "after apt-get update, no mesa-vulkan-drivers >= $MIN_MESA is available from $BACKPORTS. Check $SOURCE_FILE and your network / mirror."
fi

# 3. Install.  '-t <codename>-backports' makes apt take these packages (and
#    the libraries they need, e.g. a newer LLVM) from backports.
install_mesa() {
    # shellcheck disable=SC2086  # PACKAGES is a list of words
    apt-get "${APT_OPTS[@]}" -q install --no-install-recommends -t "$BACKPORTS" $PACKAGES
}
say "apt-get install -t $BACKPORTS $PACKAGES ..."
if ! install_mesa; then
    # Most often stale package lists (the mirror no longer has the file).
    say "install failed; refreshing package lists and trying once more ..."
    apt-get "${APT_OPTS[@]}" -q update
    install_mesa || die "apt-get could not install $PACKAGES from $BACKPORTS (see apt's message above)."
fi

MESA_VERSION="$(installed_mesa)"
dpkg --compare-versions "${MESA_VERSION:-0}" ge "$MIN_MESA" ||
    die "mesa-vulkan-drivers ${MESA_VERSION:-(not installed)} is installed, but SAPIEN needs >= $MIN_MESA. Pin it from $BACKPORTS: apt-get install -t $BACKPORTS mesa-vulkan-drivers"
say "installed mesa-vulkan-drivers $MESA_VERSION"

# 4. Probe again; this time failure is final.
say "probing again ..."
if FULL=1 probe; then
    say "OK: $(tail -n 1 "$PROBE_LOG")"
    exit 0
fi
sed 's/^/    /' "$PROBE_LOG" >&2
die "SAPIEN still finds no Vulkan device although Mesa $MESA_VERSION (lavapipe) is installed.
  Check that /usr/share/vulkan/icd.d/lvp_icd*.json exists and that VK_ICD_FILENAMES
  (now '${VK_ICD_FILENAMES:-}') and VK_DRIVER_FILES (now '${VK_DRIVER_FILES:-}') are unset
  or point at it. The probe's output is above."
