#!/bin/sh
# What our solver in the loop costs as the scene grows: whole `dc simulate` runs of 800 steps
# (the XML output included), Box2D's own 8 iterations against our PGS from Box2D's warm start to a
# residual of 1e-4 (cap 1000), plain, over-relaxed (w = 1.7), with Newton steps, with subspace
# minimization and with the solve in body space (plain and with a lagged factor), on the
# 100-circle thesis pile and a 1000-circle pile. Prints wall seconds per run (a run over 900 s is
# stopped and printed as such); ratios are taken within one run of this script.
#   sh benchmarks/bench_loop_scale.sh [OUT_DIR] [SEED]
set -e
OUT=${1:-/tmp/dc-bench-loop}
SEED=${2:-0}
DC="python3 -m deepcontact.cli.main"
python3 -c "from deepcontact.protocol import current, protocol_line; print(protocol_line(current(jobs=1)))"
BIG="--param count=1000 --param box=95 --param sigma=19"
PGS="--solver pgs --tolerance 1e-4 --max-iterations 1000"
run() {
    name=$1; shift
    start=$(date +%s.%N)
    if timeout 900 $DC simulate pile --steps 800 --seed "$SEED" -q --overwrite -o "$OUT/$name" "$@"; then
        end=$(date +%s.%N)
        echo "$name $(echo "$end - $start" | bc) s"
    else
        echo "$name stopped after 900 s"
    fi
}
run pile100-box2d
run pile100-pgs $PGS
run pile100-newton $PGS --accelerate newton
run pile100-subspace $PGS --accelerate subspace
run pile100-psor $PGS --relaxation 1.7
run pile100-bodyspace $PGS --accelerate bodyspace
run pile100-lagged $PGS --accelerate lagged
run pile1000-box2d $BIG
run pile1000-pgs $BIG $PGS
run pile1000-subspace $BIG $PGS --accelerate subspace
run pile1000-newton $BIG $PGS --accelerate newton
run pile1000-psor $BIG $PGS --relaxation 1.7
run pile1000-bodyspace $BIG $PGS --accelerate bodyspace
run pile1000-lagged $BIG $PGS --accelerate lagged
