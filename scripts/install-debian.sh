#!/usr/bin/env bash
# install-debian.sh COMMAND PACKAGE WHAT: installs Debian's PACKAGE with apt when COMMAND is
# missing, for what the tests need from outside Python (Debian's chromium for the browser tests,
# never a downloaded browser build; docker-compose to check compose.yaml, no container engine).
# When it cannot, it says so and the tests that need it are skipped with the reason.
set -euo pipefail
cmd=$1 pkg=$2 what=$3
if command -v "$cmd" >/dev/null 2>&1; then
  exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO=sudo; else
    echo "install-debian: $cmd is missing and this user cannot install $pkg; $what will be skipped" >&2
    exit 0
  fi
else
  SUDO=
fi
export DEBIAN_FRONTEND=noninteractive
if ! $SUDO apt-get install -y -qq "$pkg" >/dev/null 2>&1; then
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq "$pkg" >/dev/null || {
    echo "install-debian: apt-get could not install $pkg; $what will be skipped" >&2
    exit 0
  }
fi
command -v "$cmd"
