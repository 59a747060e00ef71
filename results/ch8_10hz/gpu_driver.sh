#!/bin/bash
# Session 12: chapter 8 (wrong rewards, collision-cut vs uncut data) at a 10 Hz control step.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch8_10hz; O=$OUT/ch8_10hz; mkdir -p $O
C="python3 scripts/reproduce_ch8.py --preset gpu --substeps 24 --recipes mixed --scale 400 --steps 50000 --no-safety --datasets mixed-cut mixed-full --out $W"
$C --stage collect > $O/collect.log 2>&1
for actor in nn_residual mlp; do
  for d in mixed-cut mixed-full; do
    $C --stage train --actor $actor --datasets $d --learners ATAC > $O/train_${actor}_${d}_atac.log 2>&1 &
    $C --stage train --actor $actor --datasets $d --learners BC > $O/train_${actor}_${d}_bc.log 2>&1 &
  done
done
wait
for actor in nn_residual mlp; do
  $C --stage figures --actor $actor --learners ATAC BC > $O/figures_$actor.log 2>&1
  mkdir -p $O/$actor; cp $W/*.md $W/*.json $W/*.png $O/$actor/ 2>/dev/null
done
cp $W/results.jsonl $O/
grep -h "\[train\]\|\[time\]" $O/train_*.log
