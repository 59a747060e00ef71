#!/bin/bash
# Session 12: chapter 8 at a 10 Hz control step with designed length bias (goal deadline 44 of
# 75 steps = 350 of 600 at 80 Hz), MLP actor, ATAC and PSPI, 4 rewards x 5 seeds.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch8_10hz_goal; O=$OUT/x; mkdir -p $O
C="python3 scripts/reproduce_ch8.py --preset gpu --substeps 24 --recipes mixed --scale 400 --steps 50000 --no-safety --goal-deadline 44 --actor mlp --out $W"
$C --stage collect --datasets mixed-full > $O/collect.log 2>&1
for d in mixed-deadline mixed-goal mixed-full; do
  for l in ATAC PSPI; do $C --stage train --datasets $d --learners $l > $O/train_${d}_${l}.log 2>&1 & done
  $C --stage train --datasets $d --learners BC > $O/train_${d}_BC.log 2>&1 &
done
wait
$C --stage figures --learners ATAC PSPI BC --datasets mixed-deadline mixed-goal mixed-full > $O/figures.log 2>&1
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch8_10hz_goal.tgz --exclude='ch8_10hz_goal/data' ch8_10hz_goal
grep -h "\[train\]\|\[time\]" $O/train_*.log
