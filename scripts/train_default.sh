#!/usr/bin/env bash
# Reproduce the shipped models of the `chessboard` profile from the recipe files in recipes/
# (recipes/README.md says what each model is). Every step is seeded; data sets and finished
# runs under runs/default are reused, so an interrupted run continues where it stopped
# (`planar-pose train --resume` continues a run from its last epoch).
#
#   1. data: free-target renders (training), the SPEC evaluation grid, the level-camera
#      renders of the SPEC-network models, and the real corpus as data sets (split by source);
#   2. the default model: the convnet, stage 1 on renders, stage 2 on renders + real train
#      sources, best epoch on the real val sources;
#   3. with SPEC=1 also the SPEC-network models A (80x60) and C (160x120), for comparison;
#   4. export to models/ (ONNX + card with accuracies measured on the exported graph), the
#      evaluation grid (docs/results.md) and models/default.
set -euo pipefail
cd "$(dirname "$0")/.."
PP=${PP:-.venv/bin/planar-pose}
D=runs/default/data   # the recipes name their data and run folders under runs/default
R=runs/default/runs
N_EVAL=${N_EVAL:-1000}  # images per synthetic evaluation set; its 20 % test split is evaluated
VERSION=${VERSION:-2.0.0}
mkdir -p "$D" "$R"

make_set() {  # OUT VARIANT SIZE BLUR COUNT SEED [PROFILE]
    [ -f "$1/manifest.json" ] || $PP data make "$1" --variant "$2" --size "$3" --blur "$4" \
        --count "$5" --seed "$6" --profile "${7:-chessboard}"
}
train_recipe() {  # NAME: recipes/NAME.toml, resumed if its run folder has a last.pt
    local out=$R/$1
    [ -f "$out/done" ] && return
    if [ -f "$out/last.pt" ]; then
        $PP train --config "recipes/$1.toml" --resume
    else
        $PP train --config "recipes/$1.toml"
    fi
    touch "$out/done"
}
export_model() {  # RUN NAME SIZE NOTES
    $PP export "$R/$1/best.pt" --name "$2" --out-dir models --version "$VERSION" \
        --eval "$D/free-s$3-b0" --eval "$D/free-s$3-b3" --eval "$D/noC-s$3-b0" \
        --eval "$D/real-s$3-b0" --eval "$D/real-s$3-b3" --notes "$4"
}

# 1. Data.
make_set "$D/train-free-s2" free 2 0 40000 401
for size in 1 2; do
    for blur in 0 1 2 3; do
        make_set "$D/free-s$size-b$blur" free "$size" "$blur" "$N_EVAL" $((2000 + 10 * size + blur))
        make_set "$D/noC-s$size-b$blur" noC "$size" "$blur" "$N_EVAL" $((1000 + 10 * size + blur))
    done
done
[ -f "$D/real-s2-b3/manifest.json" ] || $PP corpus sets "$D"

# 2. The default model.
train_recipe chessboard-convnet-160x120-pretrain
train_recipe chessboard-convnet-160x120
NOTES="Made by scripts/train_default.sh from recipes/chessboard-convnet-160x120.toml."
export_model chessboard-convnet-160x120 chessboard-convnet-160x120 2 "$NOTES"
export_model chessboard-convnet-160x120 default 2 "The default model. $NOTES"

# 3. The SPEC-network models (level camera, as the thesis), for comparison.
if [ "${SPEC:-0}" = 1 ]; then
    make_set "$D/level-noC-s1" noC 1 0 40000 101 chessboard-level
    make_set "$D/level-noC-s2" noC 2 0 12000 102 chessboard-level
    train_recipe chessboard-noC-80x60 &
    train_recipe chessboard-noC-160x120 &
    wait
    train_recipe chessboard-noC-80x60-stage2
    for wh in 80x60 160x120; do
        size=$([ "$wh" = 80x60 ] && echo 1 || echo 2)
        export_model "chessboard-noC-$wh" "chessboard-noC-$wh" "$size" \
            "SPEC network, level camera. Made by scripts/train_default.sh (recipes/)."
    done
else  # the shipped SPEC models, measured again on this run's data sets
    for wh in 80x60 160x120; do
        size=$([ "$wh" = 80x60 ] && echo 1 || echo 2)
        $PP export "models/chessboard-noC-$wh.onnx" --name "chessboard-noC-$wh" --out-dir models \
            --eval "$D/free-s$size-b0" --eval "$D/free-s$size-b3" --eval "$D/noC-s$size-b0" \
            --eval "$D/real-s$size-b0" --eval "$D/real-s$size-b3" --notes "The SPEC network \
(thesis), level camera (profile chessboard-level), kept for comparison. Recipes: \
recipes/chessboard-noC-$wh*.toml; measured again on the corpus and the free renders."
    done
fi

# 4. The evaluation grid: each shipped model on the sets of its own size (test splits).
$PP evaluate models/chessboard-convnet-160x120.onnx models/chessboard-noC-{80x60,160x120}.onnx \
    "$D"/real-s{1,2}-b{0,1,2,3} "$D"/free-s{1,2}-b{0,1,2,3} "$D"/noC-s{1,2}-b{0,1,2,3} \
    --same-size --split test --out docs/results --markdown docs/results.md \
    --title "Results of the shipped chessboard models" \
    --note "Written by \`planar-pose evaluate\` at the end of \`scripts/train_default.sh\`." \
    --note "Real sets: the corpus's test sources (train/assets/real/corpus/README.md), never used for training or model selection. Synthetic sets: $N_EVAL renders each, the 20 % test split."
$PP catalog models
echo "done: models/default.onnx; results in docs/results.md, models/README.md"
