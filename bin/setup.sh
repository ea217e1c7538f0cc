#!/usr/bin/env bash
# One-step set-up: a virtualenv in .venv with ocpipe and its pinned dependencies, plus a CPU Vulkan
# driver (Mesa lavapipe >= 24.3) when the machine has no Vulkan device. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=${VENV:-.venv}

have_vulkan_device() {
    # A GPU machine (NVIDIA driver ICD) or a Mesa new enough for SAPIEN: leave it alone.
    if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then return 0; fi
    local icd
    for icd in /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json; do
        [ -e "$icd" ] || continue
        case "$icd" in *lvp*) ;; *) return 0 ;; esac
    done
    local v
    v=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
    [ -n "$v" ] && dpkg --compare-versions "$v" ge 24.3
}

as_root() {
    if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi
}

apt_install() {  # apt_install [apt-get install options] PACKAGE...
    as_root apt-get update -qq
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

install_lavapipe() {
    if ! command -v apt-get >/dev/null 2>&1 || ! grep -qs bookworm /etc/os-release; then
        echo "ocpipe setup: no Vulkan device found and this is not Debian 12." >&2
        echo "  Install Mesa >= 24.3 with its lavapipe Vulkan driver (or a GPU driver) yourself; see README 'Rendering'." >&2
        return 0
    fi
    echo "ocpipe setup: installing Mesa lavapipe from bookworm-backports (Debian 12's Mesa 22.3 cannot render for SAPIEN)"
    if ! grep -rqs bookworm-backports /etc/apt/sources.list /etc/apt/sources.list.d/; then
        echo "deb http://deb.debian.org/debian bookworm-backports main" | as_root tee /etc/apt/sources.list.d/ocpipe-backports.list >/dev/null
    fi
    apt_install -t bookworm-backports mesa-vulkan-drivers libvulkan1
}

install_chromium() {
    # tests/test_report.py opens the Snakemake report in headless Chromium; elsewhere it skips (fails under CI)
    if ! command -v apt-get >/dev/null 2>&1 || ! grep -qs '^ID=debian' /etc/os-release; then
        echo "ocpipe setup: no chromium/chromedriver and this is not Debian: the report's browser test will skip." >&2
        echo "  Install Chromium and its matching chromedriver yourself to run it; see docs/development.md." >&2
        return 0
    fi
    echo "ocpipe setup: installing chromium and chromium-driver (the report's browser test)"
    # Debian's chromium, not Google Chrome: its driver comes from the same source package, so the versions match
    apt_install chromium chromium-driver
}

if [ "${OCPIPE_SKIP_VULKAN:-0}" != 1 ] && ! have_vulkan_device; then install_lavapipe; fi
if [ "${OCPIPE_SKIP_CHROMIUM:-0}" != 1 ] && ! { command -v chromium && command -v chromedriver; } >/dev/null 2>&1; then
    install_chromium
fi

if [ ! -x "$VENV/bin/python" ]; then "$PY" -m venv "$VENV"; fi
stamp="$VENV/.ocpipe-installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    pip_install() { "$VENV/bin/pip" install -q --disable-pip-version-check "$@" 2> >(grep -v "is ignored: it is neither" >&2); }
    # torch first and pinned: an unpinned resolve would pull a multi-GB CUDA build on CPU-only machines
    pip_install "torch==2.13.0"
    pip_install -e ".[test,cluster]"
    touch "$stamp"
fi
echo "ocpipe setup: done ($VENV)"
