#!/bin/bash
# Critic values and scores of zero-reward PSPI over 1M steps (thesis schedule) on medium-replay-goal vs -full.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:. || exit 1
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
LIMIT=${1:-570}; STEPS=${2:-1000000}
T0=$SECONDS; D=/tmp/d; mkdir -p /tmp/logs
python scripts/reproduce_ch8.py --preset gpu --recipes medium-replay --goal-deadline 350 --no-safety --stage collect --out $D > /tmp/logs/collect.log 2>&1
echo "collect rc=$? wall $((SECONDS-T0)) s"
S=results/offline_diagnostics/ch8_goal_60k_h100/critic_values_cpu/critic_values.py
P=()
for ds in goal full; do
  timeout $((LIMIT - SECONDS + T0)) python $S --cut $D/data/three_link-env3_medium-replay_cut_x100_s0.npz --full $D/data/three_link-env3_medium-replay_full_x100_s0.npz \
    --datasets $ds --learners PSPI --steps $STEPS --chunk 100000 --hidden 256 256 256 --seeds 1 --warmstart 0.1 --actor-rate published --eval-episodes 64 > /tmp/logs/$ds.log 2>&1 &
  P+=($!)
done
( while sleep 15; do cp /tmp/logs/*.log $OUT/ 2>/dev/null; done ) &
WATCH=$!
wait "${P[@]}"
kill $WATCH; cp /tmp/logs/*.log $OUT/
echo "done wall $((SECONDS-T0)) s"
grep -h '^{' /tmp/logs/goal.log /tmp/logs/full.log | python3 -c "
import json,sys
for l in sys.stdin:
    r=json.loads(l); print(r['data'], r['step'], r['wall_s'], 'first50 S/F %.2f %.2f'%(r['q_success_first50'],r['q_fail_first50']), 'last10 S/F %.2f %.2f'%(r['q_success_last10'],r['q_fail_last10']), 'score', [round(x,1) for x in r.get('score',[])])"
