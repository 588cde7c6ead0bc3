#!/usr/bin/env bash
# Writes docs/CLI.md from the commands' own --help, so that every flag is documented where the
# program defines it.
#   scripts/cli_doc.sh [BINARY]           rewrite docs/CLI.md (default binary: the build's ablenerf)
#   scripts/cli_doc.sh --check [BINARY]   exit 1 naming the first difference when docs/CLI.md is stale
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/lib.sh
check=0
if [ "${1:-}" = --check ]; then
  check=1
  shift
fi
bin=${1:-$(ablenerf_build_dir)/ablenerf}
[ -x "$bin" ] || { echo "cli_doc: $bin is missing: run scripts/setup.sh first" >&2; exit 1; }

# The help as a user sees it, with the binary's path as `ablenerf`.
help_of() { "$bin" "$@" --help | sed -e "s|^Usage: [^ ]*ablenerf|Usage: ablenerf|"; }

generate() {
  echo "# Command-line reference"
  echo
  echo "Every command's \`--help\`, as the program prints it (written by \`scripts/cli_doc.sh\`; a test"
  echo "fails when this file and the program disagree). What the commands are for: the README and"
  echo "docs/GUIDE.md."
  echo
  echo '```text'
  help_of
  echo '```'
  local cmds
  cmds=$(help_of | awk '/^Subcommands:/ { on = 1; next } on && /^  [a-z]/ { print $1 }')
  for c in $cmds; do
    echo
    echo "## ablenerf $c"
    echo
    echo '```text'
    help_of "$c"
    echo '```'
  done
}

if [ "$check" = 1 ]; then
  if ! differences=$(diff -u docs/CLI.md <(generate) 2>&1); then
    echo "cli_doc: docs/CLI.md is stale: run scripts/cli_doc.sh (first differences below)" >&2
    head -20 <<<"$differences" >&2
    exit 1
  fi
  echo "cli_doc: docs/CLI.md matches the program"
else
  generate >docs/CLI.md
  echo "cli_doc: wrote docs/CLI.md"
fi
