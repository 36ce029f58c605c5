#!/usr/bin/env bash
# Set up OS-SLAM on a fresh Debian/Ubuntu machine: system packages it lacks, then a
# virtual environment in .venv with the package installed (editable) and its test extras.
set -euo pipefail
cd "$(dirname "$0")/.."

wanted=(libusb-1.0-0 libgl1 libgomp1)
# A Python with venv support (Debian's, pyenv's, conda's) makes Debian's python3-venv unnecessary.
python3 -c 'import venv, ensurepip' 2>/dev/null || wanted+=(python3 python3-venv python3-pip)
need=()
for pkg in "${wanted[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    echo "setup: installing system packages: ${need[*]}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${need[@]}"
fi

python3 -c 'import sys; assert sys.version_info >= (3, 11), "OS-SLAM needs Python 3.11 or newer"'
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'
echo "setup: done (.venv)"
