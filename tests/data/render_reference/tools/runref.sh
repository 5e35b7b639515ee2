#!/bin/bash
# runref.sh MAT LIGHT SPP
cd "${WORK:-.}"
for seed in 1 2; do
  [ -f ref/$1-$2-s$seed.exr ] || flock "${LOCK:-/tmp/qhm-heavy.lock}" python3 "$(dirname "$0")/../mitsuba_reference.py" ref/$1.xml ref/$1-$2.json ref/$1-$2-s$seed.exr --spp $3 --seed $seed
done
