#!/bin/bash
# LfD Franka with the thesis preset at float32 matmul precision "highest" (lfd_franka.py default
# since session 18; the session-8 thesis run used the GPU default TF32): one process per task x
# strategy, side by side.
export PYTHONPATH=.  # pure JAX: no mujoco or brax needed
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false XLA_PYTHON_CLIENT_MEM_FRACTION=0.1
LIMIT=${1:-560}
T0=$SECONDS
P=()
for task in door_reaching drawer_closing; do
  for s in joint independent single_link cspace; do
    d=/tmp/lfd/$task/$s; mkdir -p $d
    timeout $((LIMIT - 15)) python scripts/lfd_franka.py --preset thesis --root results/tmp/franka_demos \
      --tasks $task --strategies $s --out $d --figures $d > $d/run.log 2>&1 &
    P+=($!)
  done
done
( while sleep 20; do tar czf $OUT/lfd_partial.tgz -C /tmp lfd 2>/dev/null; done ) &
W=$!
wait "${P[@]}"
kill $W
echo "all done wall $((SECONDS-T0)) s"
tar czf $OUT/lfd.tgz -C /tmp lfd; rm -f $OUT/lfd_partial.tgz
grep -h "trained\|error .* cm\|done in" /tmp/lfd/*/*/run.log
