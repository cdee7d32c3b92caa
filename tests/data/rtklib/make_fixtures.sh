#!/bin/sh
# Regenerate the RTKLIB .pos fixtures of tests/io/test_rtklib.py with Debian's rnx2rtkp (package rtklib,
# 2.4.3 b34). Run from anywhere: sh tests/data/rtklib/make_fixtures.sh [RTKLIB checkout]
#
# With an RTKLIB checkout (github.com/tomojitakasu/RTKLIB, commit 71db0ffa0d9735697c6adfd06fdf766d0e5ce807) the
# RINEX inputs are first cut from its test/data/rinex to the first 10 minutes (rinex/*.05o) and the ephemerides
# with a clock time before 02:00 (rinex/0759.05n). Without it, the committed trimmed RINEX files are used.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
cd "$here"
mkdir -p rinex
if [ $# -ge 1 ]; then
    src="$1/test/data/rinex"
    for f in 07590920.05o 30400920.05o; do
        # keep the header and the epochs before 00:10:00 GPST (RINEX 2.10: an epoch line starts " 05  4  2")
        awk 'BEGIN{h=1;keep=1} h{print; if ($0 ~ /END OF HEADER/) h=0; next}
             /^ 05  4  2/{ if ($5+0 >= 10) keep=0 } keep{print}' "$src/$f" > "rinex/$f"
    done
    # keep the header and the 8-line ephemeris records whose clock time (toc) is before 02:00
    awk 'BEGIN{h=1} h{print; if ($0 ~ /END OF HEADER/) h=0; next}
         { if (n == 0) { keep = ($5+0 < 2); n = 8 } if (keep) print; n-- }' "$src/07590920.05n" > rinex/07590920.05n
fi
rover=rinex/07590920.05o
base=rinex/30400920.05o
nav=rinex/07590920.05n
# base station 3040: its RINEX header's APPROX POSITION XYZ [m, ECEF]
ref="-r -3978242.4348 3382841.1715 3649902.7667"
run() {  # run OUT [rnx2rtkp options...]: kinematic L1+L2 RTK of 0759 against 3040, GPS only
    out=$1; shift
    # shellcheck disable=SC2086
    rnx2rtkp -p 2 -f 2 -m 10 -sys G $ref "$@" -o "$out" "$rover" "$base" "$nav" 2>/dev/null
    # the input paths differ between machines; the rest of the header is what rnx2rtkp wrote
    sed -i 's#^% inp file  : .*/\(rinex/[^/]*\)$#% inp file  : \1#' "$out"
}
config() {  # a -k configuration file with the given out-* options (rnx2rtkp has no switch for them)
    printf '%s\n' "$@" > "$tmp/opts.conf"
    echo "$tmp/opts.conf"
}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

run llh_deg_gpst_ell.pos -t
run llh_dms_gpst_ell.pos -t -g
run xyz_gpst.pos -t -e
run enu_gpst.pos -t -a
run llh_deg_utc_ell.pos -t -u
run llh_deg_gpst_week.pos
run llh_dms_utc_week.pos -u -g -d 1
run xyz_utc_week.pos -e -u
run enu_utc.pos -t -u -a
run llh_deg_gpst_ell_comma.pos -t -s ,
run llh_deg_gpst_geo.pos -t -k "$(config out-height=geodetic)"
run llh_dms_jst_geo.pos -t -g -k "$(config out-height=geodetic out-timesys=jst)"
run llh_deg_jst_week.pos -k "$(config out-timesys=jst)"
# single-point solutions (Q=5) of the same rover, for the quality gating
rnx2rtkp -p 0 -sys G -t -o single_gpst.pos "$rover" "$nav" 2>/dev/null
sed -i 's#^% inp file  : .*/\(rinex/[^/]*\)$#% inp file  : \1#' single_gpst.pos
