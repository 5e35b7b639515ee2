#!/usr/bin/env bash
# qhm's Monte Carlo walk against MCML 2.0 on the same medium, in one run:
# whole milk in green (mu_s 3.21 /mm, mu_a 0.0024 /mm), n 1.3, g 0, a 100 mm
# slab (semi-infinite for this medium), a normal pencil beam, one thread each.
# Prints both scattering-event rates per CPU second and their ratio.
#
#   bench/mcml-side-by-side.sh MCML_SRC_DIR [PHOTONS] [QHM_BIN]
#
# MCML_SRC_DIR holds MCML 2.0's sources (mcml.h mcmlgo.c mcmlio.c
# mcmlmain.c, V2/MCML2.0 of github.com/lhvwang/MCML); this script fetches
# nothing. It copies them to a scratch directory, makes FindDataLine's
# buffer static (it returns a pointer to a local array), builds them with
# gcc -O3, and builds a second, counting copy that adds up the photons'
# interactions (one per Hop-Drop-Spin that scatters). PHOTONS (default 1e6)
# go through MCML; the counting copy runs PHOTONS/10. QHM_BIN defaults to
# target/release/qhm. Run it under the shared lock:
#   flock /work/notes/heavy.lock bench/mcml-side-by-side.sh /path/to/MCML2.0
set -euo pipefail

src=${1:?usage: $0 MCML_SRC_DIR [PHOTONS] [QHM_BIN]}
photons=${2:-1000000}
qhm=${3:-$(dirname "$0")/../target/release/qhm}
for f in mcml.h mcmlgo.c mcmlio.c mcmlmain.c; do
    [[ -f $src/$f ]] || { echo "error: $src/$f not found (expected MCML 2.0's sources)" >&2; exit 2; }
done
[[ -x $qhm ]] || { echo "error: $qhm not found; build it: cargo build --release -p host --bin qhm" >&2; exit 2; }
qhm=$(realpath "$qhm")
[[ $photons =~ ^[0-9]+$ && $photons -ge 1000 ]] || { echo "error: PHOTONS $photons: expected an integer >= 1000" >&2; exit 2; }

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cp "$src"/mcml.h "$src"/mcmlgo.c "$src"/mcmlio.c "$src"/mcmlmain.c "$work"/
cd "$work"
# FindDataLine returns its buffer to the caller: static, or it is gone
perl -0pi -e 's/(FindDataLine\(FILE \* Fp\)\s*\{\s*)char(\s+buf\[STRLEN\];)/${1}static char$2/' mcmlio.c
grep -q 'static char        buf\[STRLEN\]' mcmlio.c || { echo "error: could not patch FindDataLine in $src/mcmlio.c" >&2; exit 2; }
gcc -O3 -w -o mcml mcmlmain.c mcmlgo.c mcmlio.c -lm

# the counting copy: a global total of Photon_Ptr->scatters, printed at the end
mkdir count && cp mcml.h mcmlgo.c mcmlio.c mcmlmain.c count/
perl -0pi -e 's/(void\s+TracePhoton\([^)]*\)\s*\{)/long long qhm_interactions = 0;\n$1/; s/(\} while \(Photon_Ptr->alive\);)/$1\n  qhm_interactions += Photon_Ptr->scatters;/' count/mcmlgo.c
perl -0pi -e 's/(ReportResult\(In_Ptr, Out_Ptr\);)/{ extern long long qhm_interactions; fprintf(stderr, "interactions %lld\\n", qhm_interactions); }\n  $1/' count/mcmlmain.c
gcc -O3 -w -o count/mcml count/mcmlmain.c count/mcmlgo.c count/mcmlio.c -lm

# Lengths in cm, coefficients in 1/cm: mu_s 32.1, mu_a 0.024; a 10 cm slab.
mci() {
    cat <<MCI
mcmli2.0
  air   1.0  0     0    0
  milk  1.3  0.024 32.1 0
end
$1 A
  air
  milk  10
  air
end
pencil
0
0.01  0.01  10
200   200   1   1
Rd_r
$2
1E-4
1
end
MCI
}

run_mcml() { # binary, photons -> CPU seconds on stdout
    mci out.mco "$2" > in.mci
    /usr/bin/time -f '%U %S' -o cpu.txt "$1" in.mci > /dev/null 2> "$work/stderr.txt" < /dev/null
    awk '{print $1 + $2}' cpu.txt
}

count_photons=$((photons / 10))
run_mcml count/mcml "$count_photons" > /dev/null
interactions=$(awk '/^interactions/ {print $2}' stderr.txt)
per_photon=$(awk -v i="$interactions" -v n="$count_photons" 'BEGIN {printf "%.1f", i / n}')
mcml_cpu=$(run_mcml ./mcml "$photons")
mcml_rate=$(awk -v p="$per_photon" -v n="$photons" -v c="$mcml_cpu" 'BEGIN {printf "%.2f", p * n / c / 1e6}')

qhm_json=$("$qhm" sim bench --json --medium whole-milk --threads 1 --no-pose --photons "$photons")
qhm_rate=$(printf '%s' "$qhm_json" | python3 -c 'import json,sys; r=json.load(sys.stdin)["report"]["rows"][0]; print("%.2f %.1f %.2f" % (r["events_per_cpu_s"]/1e6, r["mean_events_per_path"], r["cpu_seconds"]))')
read -r qhm_m qhm_per qhm_cpu <<< "$qhm_rate"

printf 'medium: whole milk, green (mu_s 3.21 /mm, mu_a 0.0024 /mm), n 1.3, g 0, 100 mm slab, pencil beam, 1 thread\n'
printf 'MCML 2.0 (gcc -O3): %s photons, %s interactions/photon (counted over %s), %.2f CPU s: %s M events per CPU s\n' \
    "$photons" "$per_photon" "$count_photons" "$mcml_cpu" "$mcml_rate"
printf 'qhm walk:           %s photons, %s events/photon, %.2f CPU s: %s M events per CPU s\n' \
    "$photons" "$qhm_per" "$qhm_cpu" "$qhm_m"
awk -v a="$qhm_m" -v b="$mcml_rate" 'BEGIN {printf "ratio qhm / MCML: %.2f\n", a / b}'
printf '%s' "$qhm_json" | python3 -c '
import json, sys
for n in json.load(sys.stdin)["report"]["stripe_noise"]:
    print("stripe profile, qhm %s walk: %.2f %% noise after %d photons in %.2f CPU s; %.1f CPU s to %.1f %%"
          % (n["walk"], 100 * n["rel_noise"], n["photons"], n["cpu_seconds"], n["cpu_seconds_to_target"], 100 * n["target_rel_noise"]))'
