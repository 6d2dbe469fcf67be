#!/usr/bin/env bash
# `make lock`: compile pyproject.toml's direct dependencies into the pinned locks with pip-tools.
#   requirements.txt          everything (runtime + evaluation + dev): what `make setup` installs
#   requirements-runtime.txt  the runtime alone (no torch, MuJoCo or Ray), within the same pins
# pip-compile keeps every pin already in a lock that still satisfies the input; add a dependency to
# pyproject.toml and run this, or upgrade one with `scripts/lock.sh --upgrade-package NAME`.
set -euo pipefail
cd "$(dirname "$0")/.."
compile=${VLA_PIP_COMPILE:-.venv/bin/pip-compile}
export CUSTOM_COMPILE_COMMAND="make lock"  # the header of each lock says how to regenerate it
opts=(--allow-unsafe --strip-extras --no-emit-index-url --no-emit-find-links --quiet "$@")
# pip-compile builds pyproject.toml's metadata with setuptools; its license-classifier warnings from
# sdists are noise here.
export PYTHONWARNINGS=ignore
"$compile" "${opts[@]}" --all-extras -o requirements.txt pyproject.toml
# torch 2.13.0 resolves to this machine's local CPU wheel (2.13.0+cpu); the lock names the public
# version, which the local wheel satisfies here and a CUDA build satisfies on a GPU workstation.
sed -i -E 's/^(torch==[0-9.]+)\+cpu$/\1/' requirements.txt
"$compile" "${opts[@]}" -c requirements.txt -o requirements-runtime.txt pyproject.toml
echo "[lock] requirements.txt: $(grep -c '^[A-Za-z]' requirements.txt) pins;" \
     "requirements-runtime.txt: $(grep -c '^[A-Za-z]' requirements-runtime.txt) pins"
