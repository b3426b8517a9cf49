#!/usr/bin/env bash
# The detector adapted to each generated building from its own recording, and
# what that changes (docs/autolabel.md, "Adapting the detector"): per building,
# generate a 300-scan sequence at 0.5 m/s with 60 true-labelled images,
# autolabel the sequence, fine-tune the shipped faster-rcnn on the labels,
# then score both detectors (AP@0.5 on the 60 images) and localize the
# sequence with each, with the full estimator and the paper's (scan matching
# off). Prints one Markdown table; everything stays in OUT.
#
#   cargo build --release && scripts/adapt_buildings.sh OUT [BUILDINGS...]   # default buildings 1-5
#
# About 4 minutes a building on 2 cores.
set -euo pipefail
out=${1:?usage: adapt_buildings.sh OUT [BUILDINGS...]}
shift
if [ $# -gt 0 ]; then buildings=("$@"); else buildings=(1 2 3 4 5); fi
bin=${CARGO_TARGET_DIR:-target}/release
for tool in datagen localize train infer; do
    [ -x "$bin/$tool" ] || { echo "no $bin/$tool: run cargo build --release first" >&2; exit 1; }
done
mkdir -p "$out"
echo '{"scan_match": {"enabled": false}}' > "$out/paper-estimator.json"
ap() { "$bin/infer" eval --checkpoint "$1" --data "$2" | awk '/^AP@0.5/ {print $2}'; }
ate() { awk '/^fused all/ {print $NF * 1000}' "$1"; }
echo "| building | label precision | label recall | AP@0.5 shipped | AP@0.5 adapted | ATE mm shipped | ATE mm adapted | paper's ATE mm shipped | paper's ATE mm adapted |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for n in "${buildings[@]}"; do
    b="$out/building-$n"
    [ -f "$b/data/datagen.json" ] ||
        "$bin/datagen" --out "$b/data" --building "$n" --frames 300 --speed 0.5 --images 60 --train 0 > "$b.datagen.log" 2>&1
    rm -rf "$b/labels" "$b/adapted"
    CI=true "$bin/localize" autolabel --sequence "$b/data/sequence" --out "$b/labels" > "$b.autolabel.log" 2>&1
    CI=true "$bin/train" --backbone faster-rcnn --pretrained checkpoints/faster-rcnn --data "$b/labels" \
        --out "$b/adapted" --epochs 3 --lr 2e-4 > "$b.train.log" 2>&1
    score=$(python3 -c "import json,sys; s=json.load(open(sys.argv[1]))['against_truth'][0]; print('%.3f | %.3f' % (s['precision'], s['recall']))" "$b/labels/autolabel.json")
    row="| $n | $score | $(ap checkpoints/faster-rcnn "$b/data/detection") | $(ap "$b/adapted/checkpoint" "$b/data/detection")"
    for estimator in full paper; do
        config=()
        [ "$estimator" = paper ] && config=(--config "$out/paper-estimator.json")
        for detector in shipped adapted; do
            checkpoint=checkpoints/faster-rcnn
            [ "$detector" = adapted ] && checkpoint="$b/adapted/checkpoint"
            run="$b/run-$estimator-$detector"
            rm -rf "$run"
            CI=true "$bin/localize" run --sequence "$b/data/sequence" --checkpoint "$checkpoint" "${config[@]}" \
                --out "$run" > "$run.log" 2>&1
            row="$row | $(ate "$run.log")"
        done
    done
    echo "$row |"
done
