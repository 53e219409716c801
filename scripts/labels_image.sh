#!/usr/bin/env bash
# The README's labels picture: the ct-chest sample with its painted solids as segmentation labels, shown by
# examples/ct-chest-labels.toml (post-classified technique) over the ct-bone preset.
#   make labels-image        (OUT=out ISPLAT=.venv/bin/isplat bash scripts/labels_image.sh docs/img)
set -euo pipefail
OUT=${OUT:-out}
ISPLAT=${ISPLAT:-.venv/bin/isplat}
IMG=${1:-docs/img}
mkdir -p "$OUT/labels" "$IMG"
"$ISPLAT" sample ct-chest -o "$OUT/labels/chest.npy" --labels "$OUT/labels/chest-labels.npy" --force -q
"$ISPLAT" augment "$OUT/labels/chest.npy" -o "$OUT/labels/chest.aug.h5" --spacing 1,1,1.5 --orientation LPS \
    --labels "$OUT/labels/chest-labels.npy" --index --force -q
"$ISPLAT" render examples/ct-chest-labels.toml --set data.augmented="$OUT/labels/chest.aug.h5" \
    --set labels.names="$OUT/labels/chest-labels.json" --size 256 -o "$IMG/demo-ct-chest-labels.png" --force
