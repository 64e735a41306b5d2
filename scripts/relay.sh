#!/usr/bin/env bash
# The relay: a long training run carried across stretches of work and machines. The current
# run trains CrossMaskNet (FPFH descriptor inputs) on the first 20 ModelNet40 categories
# only (--categories seen), to measure it on the other 20. Finished runs are kept beside it:
# relay/crossmasknet_fpfh_modelnet40/ (all 40 categories, 20 epochs: shipped as
# crossmasknet_modelnet40) and relay/crossmasknet_modelnet40/ (coordinates alone, stopped).
#
#   scripts/relay.sh start      resume the run in the background (nohup nice), logging to train.log
#   scripts/relay.sh pause      SIGSTOP it (while anything is timed)
#   scripts/relay.sh continue   SIGCONT it
#   scripts/relay.sh stop       SIGTERM: it saves where it stands (mid-epoch too) and exits
#   scripts/relay.sh status     running or not, and the last epoch logged
#
# Everything the run needs to go on is in its folder ($RUN below): run.json (the
# configuration), checkpoint.safetensors (weights, optimiser, schedule position, RNG, the
# unfinished epoch's progress), log.csv, curve.png and train.log. Commit that folder after
# `stop`. `start` on a fresh clone continues from the committed checkpoint.
set -euo pipefail
cd "$(dirname "$0")/.."
RUN=relay/crossmasknet_fpfh_seen20
PIDFILE="$RUN/.pid"
DATA="${MASKNET_DATA:-../shared/data/modelnet40/modelnet40_1024_int16.npz}"
MASKNET="${MASKNET_BIN:-.venv/bin/masknet}"

running() { [[ -f "$PIDFILE" ]] && kill -0 "$(cat "$PIDFILE")" 2>/dev/null; }

case "${1:-status}" in
start)
    if running; then echo "already running (pid $(cat "$PIDFILE"))"; exit 0; fi
    [[ -f "$DATA" ]] || { echo "relay: ModelNet40 not found at $DATA (set MASKNET_DATA)" >&2; exit 2; }
    mkdir -p "$RUN"
    # The recipe: fixed for the whole run (--resume refuses any change but --epochs,
    # --threads, --max-minutes and --checkpoint-minutes).
    nohup nice -n 19 "$MASKNET" train --model crossmasknet --model-config '{"descriptors": "fpfh"}' \
        --loss bce --data "$DATA" --categories seen \
        --output "$RUN" --epochs 20 --batch-size 32 --lr 5e-4 --lr-schedule cosine \
        --precision fp32 --threads 2 --seed 0 --checkpoint-minutes 10 --resume \
        >>"$RUN/train.log" 2>&1 &
    echo $! >"$PIDFILE"
    echo "started (pid $!); log: $RUN/train.log"
    ;;
pause) running && kill -STOP "$(cat "$PIDFILE")" && echo paused ;;
continue) running && kill -CONT "$(cat "$PIDFILE")" && echo continued ;;
stop)
    if ! running; then echo "not running"; exit 0; fi
    pid=$(cat "$PIDFILE")
    kill -CONT "$pid" 2>/dev/null || true
    kill -TERM "$pid"
    # It finishes its current step (a few seconds), saves and exits.
    for _ in $(seq 1 120); do kill -0 "$pid" 2>/dev/null || break; sleep 1; done
    if kill -0 "$pid" 2>/dev/null; then echo "still running after 120 s" >&2; exit 1; fi
    rm -f "$PIDFILE"
    tail -n 2 "$RUN/train.log"
    ;;
status)
    if running; then echo "running (pid $(cat "$PIDFILE"))"; else echo "not running"; fi
    [[ -f "$RUN/log.csv" ]] && tail -n 1 "$RUN/log.csv" || echo "no epoch finished yet"
    ;;
*) echo "usage: scripts/relay.sh start|pause|continue|stop|status" >&2; exit 2 ;;
esac
