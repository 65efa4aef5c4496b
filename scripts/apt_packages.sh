# Sourced by the texture install scripts: ensure_packages NAME PACKAGE... installs the Debian
# packages not yet installed (root and apt-get needed; NAME prefixes the error).
ensure_packages() {
  local name=$1 missing="" p
  shift
  for p in "$@"; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
  [ -z "$missing" ] && return 0
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    apt-get install -y -q $missing >/dev/null 2>&1 \
      || { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q $missing >/dev/null; }
  else
    echo "$name: need root and apt-get to install:$missing" >&2
    exit 1
  fi
}
