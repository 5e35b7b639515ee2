#!/bin/bash
# runref.sh MAT LIGHT SPP [SEEDS]: SEEDS renders (an even count, 2 unless given) of SPP
# samples per pixel, seeds 1 to SEEDS, merged into the reference's two halves
# ref/MAT-LIGHT-s1.exr and -s2.exr (merge_seeds.py)
cd "${WORK:-.}"
n=${4:-2}
for seed in $(seq 1 "$n"); do
  [ -f ref/$1-$2-seed$seed.exr ] || flock "${LOCK:-/tmp/qhm-heavy.lock}" python3 "$(dirname "$0")/../mitsuba_reference.py" ref/$1.xml ref/$1-$2.json ref/$1-$2-seed$seed.exr --spp $3 --seed $seed
done
python3 "$(dirname "$0")/merge_seeds.py" $1-$2 $3 $(seq 1 "$n")
