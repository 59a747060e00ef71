#!/bin/bash
# Session 15 call A: Meta-World-like data (expert with sigma-0.5 noise, `medium` recipe) at 10 Hz, MLP actor, 150 k steps: ATAC with the three wrong rewards on -arrive, -goal, -full, and BC.
END=$(( $(date +%s) + 565 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch8_10hz_medium; O=$OUT/x; mkdir -p $O $W
C="python3 scripts/reproduce_ch8.py --preset gpu --substeps 24 --recipes medium --scale 1600 --steps 150000 --chunk 50000 --curve --no-safety --goal-deadline 44 --actor mlp --rewards zero random negated --out $W"
timeout $((END-$(date +%s))) $C --stage collect --datasets medium-full medium-goal medium-arrive > $O/collect.log 2>&1
for d in medium-arrive medium-goal medium-full; do
  timeout $((END-$(date +%s)-25)) $C --stage train --datasets $d --learners ATAC > $O/train_${d}_ATAC.log 2>&1 &
done
timeout $((END-$(date +%s)-25)) $C --stage train --datasets medium-arrive medium-goal medium-full --learners BC > $O/train_BC.log 2>&1 &
wait
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch8_10hz_medium.tgz --exclude='ch8_10hz_medium/data' ch8_10hz_medium
grep -h "\[collect\]\|\[train\]\|\[time\]\|\[curve\]\|Error\|error" $O/*.log | head -60
