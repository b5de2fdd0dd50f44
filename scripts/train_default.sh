#!/usr/bin/env bash
# Reproduce the shipped models from scratch for the `chessboard` profile (about 75 min on an
# otherwise idle 2-core machine):
#   1. synthetic data: training sets (noC, blur 0; blur 1-3 are mixed in on the fly by `train`),
#      the evaluation grid {noC, C} x size {1, 2} x blur {0..3}, small rehearsal sets;
#   2. the real photos as data sets (both sizes, blur 0..3, split by stereo moment);
#   3. A (noC, 80x60) and C (noC, 160x120) trained in parallel, one core each (Adam, batch
#      norm folded away on export), then A 12 more epochs from its last state;
#   4. Ar, Cr: A and C fine-tuned on the real train split (all blur levels) plus a synthetic
#      rehearsal set so that class 0 and the far classes, absent from the photos, are kept;
#   5. export of the four to models/ (ONNX + card, accuracy measured on the exported graph);
#   6. the full evaluation grid written to docs/results.md (+ docs/results/);
#   7. models/default.onnx + default.json = $DEFAULT.
# Every step is seeded; existing data sets and finished runs in $WORK are reused.
set -euo pipefail
cd "$(dirname "$0")/.."
PP=${PP:-.venv/bin/planar-pose}
WORK=${WORK:-runs/default}
PROFILE=${PROFILE:-chessboard}
N_EVAL=${N_EVAL:-2500}     # images per evaluation set; its 20 % test split is evaluated
DEFAULT=${DEFAULT:-$PROFILE-noC-80x60}  # best synthetic + real test of the four (docs/results.md)
VERSION=${VERSION:-1.0.0}
D=$WORK/data
R=$WORK/runs
mkdir -p "$D" "$R"
STATUS="Below the project's bar of 97 % on synthetic noC: the network learns class 0, near/far and \
the board's orientation (x/y side up to a half turn) but only partly the square-colour parity that \
tells opposite quadrants apart; see docs/results.md. Trained for a level camera (roll within 5 \
degrees): photos taken at a large roll get a wrong quadrant. The real test split is 6 photos."

make_set() {  # OUT VARIANT SIZE BLUR COUNT SEED
    [ -f "$1/manifest.json" ] || $PP data make "$1" --variant "$2" --size "$3" --blur "$4" \
        --count "$5" --seed "$6" --profile "$PROFILE"
}

# 1-2. Data.
make_set "$D/train-noC-s1" noC 1 0 40000 101
make_set "$D/train-noC-s2" noC 2 0 12000 102
for size in 1 2; do
    make_set "$D/rehearse-noC-s$size" noC "$size" 0 600 $((300 + size))
    for blur in 0 1 2 3; do
        [ -f "$D/real-s$size-b$blur/manifest.json" ] || $PP realset \
            train/assets/real/chessboard-stereo "$D/real-s$size-b$blur" --size "$size" --blur "$blur" \
            --profile "$PROFILE" --seed 0
    done
done
for size in 1 2; do
    for variant in noC C; do
        for blur in 0 1 2 3; do
            make_set "$D/$variant-s$size-b$blur" "$variant" "$size" "$blur" "$N_EVAL" \
                $((1000 + 10 * size + blur))
        done
    done
done

# 3. A and C in parallel (Adam, cosine schedule, batch norm, best epoch on val).
train_run() {  # NAME DATA EPOCHS LR SEED
    [ -f "$R/$1/best.pt" ] || $PP train "$2" --out "$R/$1" --epochs "$3" --batch-size 32 \
        --optimizer adam --lr "$4" --weight-decay 0 --patience 0 --seed "$5" --threads 1 \
        > "$R/$1.log" 2>&1
}
train_run "$PROFILE-noC-80x60-stage1" "$D/train-noC-s1" 12 0.003 1 &
train_run "$PROFILE-noC-160x120" "$D/train-noC-s2" 12 0.002 2 &
wait
# A was still improving after its 12 epochs: 12 more from its last state (warm restart).
[ -f "$R/$PROFILE-noC-80x60/best.pt" ] || $PP train "$D/train-noC-s1" \
    --init "$R/$PROFILE-noC-80x60-stage1/last.pt" --out "$R/$PROFILE-noC-80x60" --epochs 12 \
    --batch-size 32 --optimizer adam --lr 0.001 --weight-decay 0 --patience 0 --seed 3 \
    --threads 2 > "$R/$PROFILE-noC-80x60.log" 2>&1

# 4. Fine-tuning on the real train split (+ rehearsal), 15 epochs as in the thesis.
for size in 1 2; do
    wh=$([ "$size" = 1 ] && echo 80x60 || echo 160x120)
    run=$PROFILE-noC-$wh
    [ -f "$R/$run-real/best.pt" ] || $PP train "$D"/real-s$size-b{0,1,2,3} \
        "$D/rehearse-noC-s$size" --init "$R/$run/best.pt" --out "$R/$run-real" \
        --epochs 15 --batch-size 16 --lr 0.001 --patience 0 --seed "$size" --threads 1

    # 5. Export (accuracy on the test splits goes in the card).
    for name in "$run" "$run-real"; do
        $PP export "$R/$name/best.pt" --name "$name" --out-dir models --version "$VERSION" \
            --eval "$D/noC-s$size-b0" --eval "$D/noC-s$size-b3" --eval "$D/C-s$size-b0" \
            --eval "$D/real-s$size-b0" --eval "$D/real-s$size-b3" \
            --notes "Made by scripts/train_default.sh. $STATUS"
    done
done

# 6. The grid: each model on the sets of its own size (test splits).
$PP evaluate models/$PROFILE-noC-{80x60,80x60-real,160x120,160x120-real}.onnx \
    "$D"/noC-s{1,2}-b{0,1,2,3} "$D"/C-s{1,2}-b{0,1,2,3} "$D"/real-s{1,2}-b{0,1,2,3} \
    --same-size --split test --out docs/results --markdown docs/results.md \
    --title "Results of the shipped $PROFILE models" \
    --note "Written by \`planar-pose evaluate\` at the end of \`scripts/train_default.sh\`." \
    --note "Synthetic sets: $N_EVAL renders each, the 20 % test split evaluated. Real sets: the 26 chessboard-stereo photos; their test split is 6 photos (3 stereo moments), all near, no class 0: one photo is 16.7 points."

# 7. The default model.
size=$([ "${DEFAULT#*160x120}" != "$DEFAULT" ] && echo 2 || echo 1)
$PP export "$R/$DEFAULT/best.pt" --name default --out-dir models --version "$VERSION" \
    --eval "$D/noC-s$size-b0" --eval "$D/noC-s$size-b3" --eval "$D/C-s$size-b0" \
    --eval "$D/real-s$size-b0" --eval "$D/real-s$size-b3" \
    --notes "The default model is $DEFAULT (models/$DEFAULT.onnx). Made by scripts/train_default.sh. $STATUS"
echo "done: models/default.onnx = $DEFAULT; results in docs/results.md"
