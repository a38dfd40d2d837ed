#!/bin/sh
# The industrial dryer from four PRBS experiments to a learned mode bank and a diagnosis.
# Run from anywhere: sh examples/learning/learn_dryer.sh   (writes into examples/learning/)
# The "plant" here is the published dryer spec, simulated; with a real dryer the four CSV files
# would come from running the PRBS on the heater in each condition.
set -e
cd "$(dirname "$0")"
J="${JMLGDSL:-jmlgdsl}"
SPEC=../../specs/dryer.jmlg

# 1. Step tests: current 15 -> 20 % at t = 50 s, one per mode; FOPDT fits give gain, time constant
#    and dead time (the figures show fit against data), and a first-order bank to compare with.
awk 'BEGIN { print "time,current"; for (t = 1; t <= 400; t++) print t "," (t <= 50 ? 15 : 20) }' > step.csv
seed=11
for mode in normal fan grill fan_grill; do
  $J simulate $SPEC --inputs step.csv --modes "1-400:$mode" --seed $seed -o "step_$mode.csv"
  seed=$((seed + 1))
done
$J learn --template $SPEC --fopdt \
  --mode normal=step_normal.csv --mode fan=step_fan.csv --mode grill=step_grill.csv \
  --mode fan_grill=step_fan_grill.csv --figures figures/step -o dryer_fopdt.jmlg

# 2. Experiment design: 6 cells (63 bits) clocked every 16 s = 1008 s, heater current 15 +- 5 %.
#    The longest pulse (6 x 16 = 96 s) must outlast the settling time we expect (about 3 x 30 s).
$J prbs --cells 6 --clock 16 --amplitude 5 --around 15 --name current --dt 1 --settling 90 -o prbs.csv

# 3. One experiment per mode (here simulated from the published models, each with its own noise).
seed=1
for mode in normal fan grill fan_grill; do
  $J simulate $SPEC --inputs prbs.csv --modes "1-1008:$mode" --seed $seed -o "$mode.csv"
  seed=$((seed + 1))
done

# 4. Learn: the number of states chosen by BIC, EM from an ARX start, validation figures; the
#    template supplies names, units, mode descriptions, transitions and prior.
$J learn --template $SPEC --order auto \
  --mode normal=normal.csv --mode fan=fan.csv --mode grill=grill.csv --mode fan_grill=fan_grill.csv \
  --figures figures -o dryer_learned.jmlg

# 5. Diagnose the published fault sequence with the learned bank and with the true one.
$J run dryer_learned.jmlg ../dryer_seq1.csv --filter la-rbpf --particles 50 --seed 1 -o run_learned.csv
$J run $SPEC ../dryer_seq1.csv --filter la-rbpf --particles 50 --seed 1 -o run_true.csv
$J plot run_learned.csv --truth ../dryer_seq1.csv --title "Learned dryer bank, sequence No. 1" -o figures/diagnosis_learned.png
$J plot run_true.csv --truth ../dryer_seq1.csv --title "Published dryer bank, sequence No. 1" -o figures/diagnosis_true.png
