#!/usr/bin/env bash
# make demo: sample data -> augment -> index -> render -> stats, images under $OUT.
set -euo pipefail
: "${OUT:=out}"; : "${ISPLAT:=isplat}"
mkdir -p "$OUT"
echo "demo: pipeline steps are filled in as the stages land" >&2
