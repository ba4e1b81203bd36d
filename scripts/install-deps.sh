#!/usr/bin/env bash
# Installs the Debian packages cip needs to build and test, if any is missing (fast when all are present).
# Usage: bash scripts/install-deps.sh [extra-package ...]   (run as root, or with sudo available)
set -euo pipefail
packages=(cmake ninja-build g++ pkg-config
  libeigen3-dev libtbb-dev zlib1g-dev libbz2-dev libgdcm-dev libcli11-dev nlohmann-json3-dev libopenexr-dev libpng-dev
  libopenvdb-dev libboost-iostreams-dev libembree-dev libopenimageio-dev
  libgtest-dev libgmock-dev libbenchmark-dev libtinygltf-dev libzstd-dev libmeshoptimizer-dev draco
  libopenmpi-dev openmpi-bin  # extract across processes under mpirun (docs/mpi.md)
  pybind11-dev python3-pybind11 python3-numpy python3-pytest python3-skimage python3-meshio python3-openimageio
  python3-nibabel python3-vtk9 python3-pydicom python3-openvdb teem-apps "$@")  # independent readers/writers for the reader tests
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
echo "installing: ${missing[*]}" >&2
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
