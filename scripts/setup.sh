#!/usr/bin/env bash
# Set up convodrive on a fresh Debian or Ubuntu machine: system libraries, a virtual environment
# in .venv, and the package with the extras the demo needs. Safe to run again.
#
#   scripts/setup.sh          everything `convodrive demo` needs
#   scripts/setup.sh --dev    and the test tools
set -euo pipefail
cd "$(dirname "$0")/.."

dev=0
[ "${1:-}" = "--dev" ] && dev=1

# espeak-ng makes the tests' speech; ffmpeg brings ffprobe for checking videos; EGL and OSMesa are
# the two headless GL routes for the renderer and MuJoCo; PortAudio (with ALSA's PulseAudio plugin)
# is live audio.
apt_packages=(espeak-ng ffmpeg libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 libportaudio2 libasound2-plugins)
# The tests also open the avatar's live window on a virtual X display, run live conversations on
# their own PulseAudio servers, load the live page in headless Chromium, and check the exported
# glTF with the Khronos validator (an npm package, run by node).
[ "$dev" = 1 ] && apt_packages+=(xvfb pulseaudio pulseaudio-utils chromium)
# Reachy Mini's daemon (the reachy_mini backend's tests): PyGObject and pycairo build from source
# (cairo, girepository, pkg-config) and the daemon loads the GStreamer typelibs even with --no-media.
[ "$dev" = 1 ] && apt_packages+=(libcairo2-dev libgirepository1.0-dev pkg-config gir1.2-gstreamer-1.0 gir1.2-gst-plugins-base-1.0)
missing=()
for pkg in "${apt_packages[@]}"; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
# node and npm may come from elsewhere than Debian (their own packages conflict): ask for them only
# when neither program is there.
if [ "$dev" = 1 ] && ! { command -v node && command -v npm; } >/dev/null 2>&1; then
    missing+=(nodejs npm)
fi
if [ ${#missing[@]} -gt 0 ]; then
    sudo=""
    [ "$(id -u)" -ne 0 ] && sudo="sudo"
    echo "setup: installing system packages: ${missing[*]}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
fi

python=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$python" -m venv .venv

# pip runs quietly: its output is shown only when it fails. Hidden on success: this machine's
# notes about index locations, and setuptools' notice that the install is editable (ours is on
# purpose: retargeting/ and backends/ install under the convodrive namespace through a finder).
pip_log=$(mktemp)
trap 'rm -f "$pip_log"' EXIT
pip_quiet() {
    if ! PYTHONWARNINGS="ignore:Editable installation" \
        .venv/bin/python -m pip --disable-pip-version-check -q "$@" >"$pip_log" 2>&1; then
        grep -v '^WARNING: Location' "$pip_log" >&2 || true
        echo "setup: pip install failed (above)" >&2
        exit 1
    fi
}
echo "setup: installing Python packages into .venv"
pip_quiet install -U pip setuptools wheel
extras="speech,sim,render,hardware,live,neural,eval"
[ "$dev" = 1 ] && extras="$extras,train,frontend,pipecat,livekit,dev"  # the agent adapters: ~900 MB, dev only
pip_quiet install -e ".[$extras]"
# pyrender 0.1.45 pins PyOpenGL==3.1.0, which breaks MuJoCo's EGL/OSMesa bindings. The render
# extra installs pyrender's real dependencies with PyOpenGL>=3.1.7; pyrender itself goes in
# without its pin. See README, "Headless GL and the PyOpenGL pin".
pip_quiet install --no-deps "pyrender==0.1.45"
.venv/bin/python -c "import convodrive, OpenGL; assert tuple(map(int, OpenGL.__version__.split('.')[:3])) >= (3, 1, 7), OpenGL.__version__" \
    || { echo "setup: PyOpenGL is older than 3.1.7; MuJoCo's headless GL would break" >&2; exit 1; }
if [ "$dev" = 1 ] && [ ! -d tools/node/node_modules/gltf-validator ]; then
    if ! npm install --no-audit --no-fund --prefer-offline --prefix tools/node gltf-validator@2.0.0-dev.3.10 \
        >"$pip_log" 2>&1; then
        grep -v '^npm warn' "$pip_log" >&2 || true
        echo "setup: npm install of gltf-validator failed (above)" >&2
        exit 1
    fi
fi
# Real recorded voices for the real-voice tests (Debian packages, by name, into a cache outside git).
if [ "$dev" = 1 ]; then
    scripts/real_voices.sh >/dev/null || { echo "setup: scripts/real_voices.sh failed (above)" >&2; exit 1; }
fi
# Reachy Mini's daemon in a venv of its own: reachy-mini pins onnxruntime 1.27, mujoco 3.3 and
# websockets < 16, which would downgrade ours; the backend only speaks its WebSocket. About 3 min
# (PyGObject builds) and 407 MB.
if [ "$dev" = 1 ] && ! .venv-reachy/bin/python -c "import reachy_mini" >/dev/null 2>&1; then
    [ -x .venv-reachy/bin/python ] || "$python" -m venv .venv-reachy
    if ! .venv-reachy/bin/python -m pip --disable-pip-version-check -q install "reachy-mini[mujoco]==1.13.0" \
        >"$pip_log" 2>&1; then
        grep -v '^WARNING: Location' "$pip_log" >&2 || true
        echo "setup: pip install of Reachy Mini's daemon failed (above)" >&2
        exit 1
    fi
fi
# Reachy Mini's official client in .venv too, for -B reachy_mini.client=sdk and its test:
# reachy-mini without its dependencies (its pins, onnxruntime==1.27, websockets<16 and
# huggingface-hub<2, would downgrade ours; its client runs on ours), then the five its client
# imports that we lack (PyGObject builds from source with the apt packages above). pip check then
# lists reachy-mini's unmet pins: expected, the daemon's own venv is .venv-reachy.
if [ "$dev" = 1 ] && ! .venv/bin/python -c "import reachy_mini" >/dev/null 2>&1; then
    pip_quiet install --no-deps "reachy-mini==1.13.0" asgiref "PyGObject>=3.42.2,<=3.46.0" pycairo zeroconf ifaddr
fi
echo "setup: ready (.venv)"
