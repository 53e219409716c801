#!/usr/bin/env bash
# make demo: sample data -> augment -> index -> render -> stats, images under $OUT.
set -euo pipefail
: "${OUT:=out}"; : "${ISPLAT:=isplat}"
mkdir -p "$OUT"
run() { echo "+ $*" >&2; "$@"; }

for s in head engine; do
  run "$ISPLAT" sample "$s" -o "$OUT/$s.npy" --force >/dev/null
  run "$ISPLAT" augment "$OUT/$s.npy" -o "$OUT/$s.aug.h5" --force
  run "$ISPLAT" index "$OUT/$s.aug.h5" -o "$OUT/$s.idx.h5" --force
done

data() { echo --set "data.augmented=$OUT/$1.aug.h5" --set "data.index=$OUT/$1.idx.h5"; }
# shaded bone (the paper's H1)
run "$ISPLAT" render examples/head.toml $(data head) -o "$OUT/head-bone.png" --force -v
# a perspective view of the same scene (the paper's Figure 7a)
run "$ISPLAT" render examples/head.toml $(data head) --set camera.projection=perspective \
    --set camera.azimuth=60 --set camera.fov=40 -o "$OUT/head-perspective.png" --force -v
# a cutting plane through faint skin and bone (the paper's H2)
run "$ISPLAT" render examples/head-cut.toml $(data head) -o "$OUT/head-cut.png" --force -v
# the semi-transparent engine (the paper's E1), perspective
run "$ISPLAT" render examples/engine.toml $(data engine) -o "$OUT/engine.png" --force -v
# a 12-view orbit as an animated GIF
run "$ISPLAT" render examples/head.toml $(data head) --set views.orbit_steps=12 --set image.width=256 \
    --set image.height=256 -o "$OUT/head-orbit.gif" --force
# a camera path through three keyframes: 24 frames at constant angular speed, as an animated GIF
run "$ISPLAT" render examples/head.toml $(data head) --set image.width=256 --set image.height=256 \
    --set 'views.path=[{azimuth = -40, elevation = 0}, {azimuth = 60, elevation = 35, zoom = 1.6}, {azimuth = 160, elevation = 10}]' \
    --set views.frames=24 -o "$OUT/head-path.gif" --force

# your own scan: a CT in Hounsfield units (here the int16 ct-head sample, a .npy: its orientation, LPS, is
# given) and a preset, in two commands, as README's "Your own scan"
run "$ISPLAT" sample ct-head -o "$OUT/ct.npy" --force >/dev/null
run "$ISPLAT" augment "$OUT/ct.npy" -o "$OUT/ct.aug.h5" --orientation LPS --index --force
for p in ct-bone ct-skin; do
  run "$ISPLAT" render "$OUT/ct.aug.h5" --preset "$p" -o "$OUT/$p.png" --force
done
# and an MRI head (the uint16 mr-head sample)
run "$ISPLAT" sample mr-head -o "$OUT/mr.npy" --force >/dev/null
run "$ISPLAT" augment "$OUT/mr.npy" -o "$OUT/mr.aug.h5" --orientation LPS --index --force
run "$ISPLAT" render "$OUT/mr.aug.h5" --preset mri-t1-head -o "$OUT/mri-t1-head.png" --force
# a maximum-intensity projection (render.mode = "mip", docs/mip.md) of the int16 ct-chest sample, seen from the
# left: densities above -500 HU are of interest, the maximum shown through the window -200..1300 HU
run "$ISPLAT" sample ct-chest -o "$OUT/chest.npy" --force >/dev/null
run "$ISPLAT" augment "$OUT/chest.npy" -o "$OUT/chest.aug.h5" --orientation LPS --index --force
run "$ISPLAT" render "$OUT/chest.aug.h5" --set 'camera.view="left"' --set 'transfer.units="data"' \
    --set 'transfer.opacity=[[-1024, 0.0], [-501, 0.0], [-500, 1.0], [3071, 1.0]]' --set 'render.mode="mip"' \
    --set 'render.window=[-200, 1300]' -o "$OUT/ct-chest-mip.png" --force -v
if "$ISPLAT" stats --help >/dev/null 2>&1; then
  run "$ISPLAT" stats "$OUT/head.aug.h5" "$OUT/head.idx.h5" --scene examples/head.toml $(data head) \
      | tee "$OUT/head-stats.txt"
fi
echo "demo: images in $OUT/" >&2
ls -1 "$OUT"/*.png "$OUT"/*.gif >&2
