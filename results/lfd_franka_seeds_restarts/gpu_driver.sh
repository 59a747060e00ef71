#!/bin/bash
# Ten-seed replication of the Franka comparison with lfd_franka.py's session-18 defaults:
# 3 restarts per fold (the kept model is checked on the fold's own training starts), 4 Euler
# sub-steps per 0.05 s control step, float32 matmuls at highest precision; everything else as in
# results/lfd_franka_seeds/gpu_driver.sh. Seeds from the arguments (two calls of five).
export PYTHONPATH=.  # pure JAX: no mujoco or brax needed
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false XLA_PYTHON_CLIENT_MEM_FRACTION=0.15
LIMIT=570
T0=$SECONDS
P=()
for seed in "$@"; do
  d=/tmp/lfd/seed_$seed; mkdir -p $d
  timeout $((LIMIT - 15)) python scripts/lfd_franka.py --root results/tmp/franka_demos \
    --strategies joint independent single_link cspace --seed $seed --out $d --figures $d \
    > $d/run.log 2>&1 &
  P+=($!)
done
( while sleep 20; do tar czf $OUT/lfd_partial.tgz -C /tmp lfd 2>/dev/null; done ) &
W=$!
wait "${P[@]}"
kill $W
echo "all done wall $((SECONDS-T0)) s"
tar czf $OUT/lfd.tgz -C /tmp lfd; rm -f $OUT/lfd_partial.tgz
grep -h "done in\|kept" /tmp/lfd/*/run.log | cut -c1-200
