#!/bin/bash
# Session 12: random and negated rewards at 10 Hz, MLP actor, 150 k steps with curves: absorbing-goal data vs no length bias.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch8_10hz_long; O=$OUT/x; mkdir -p $O
C="python3 scripts/reproduce_ch8.py --preset gpu --substeps 24 --recipes mixed --scale 400 --steps 150000 --chunk 50000 --curve --no-safety --goal-deadline 44 --actor mlp --rewards random negated --out $W"
$C --stage collect --datasets mixed-full > $O/collect.log 2>&1
for d in mixed-goal mixed-full; do
  for l in ATAC PSPI; do $C --stage train --datasets $d --learners $l > $O/train_${d}_${l}.log 2>&1 & done
done
wait
true
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch8_10hz_long.tgz --exclude='ch8_10hz_long/data' ch8_10hz_long
grep -h "\[train\]\|\[time\]\|\[curve\]" $O/train_*.log
