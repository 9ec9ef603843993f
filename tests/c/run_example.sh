#!/usr/bin/env bash
# Installs a built penumbra into a temporary prefix and checks that a
# standalone consumer builds and runs against it, both through CMake
# (find_package(penumbra) + penumbra::penumbra) and through pkg-config.
#
#   run_example.sh BUILD_DIR SOURCE_DIR
#
# Environment: PYTHON (interpreter that writes the test env map; default
# python3 on PATH), PENUMBRA_EXAMPLE_CFLAGS (extra compile and link flags for
# the consumer, e.g. the sanitizer flags of a sanitized build), KEEP_TMP=1 to
# keep the temporary directory. Exit status: 0 all passed, 1 a check failed,
# 77 skipped (no Python to write the input file, or no stb_image to read it).
set -u

if [ $# -ne 2 ]; then
    echo "usage: $0 BUILD_DIR SOURCE_DIR" >&2
    exit 2
fi
BUILD_DIR=$(cd "$1" && pwd) || exit 2
SOURCE_DIR=$(cd "$2" && pwd) || exit 2
EXTRA_FLAGS=${PENUMBRA_EXAMPLE_CFLAGS:-}

PY=${PYTHON:-}
if [ -z "$PY" ]; then
    PY=$(command -v python3 || true)
fi
if [ -z "$PY" ] || ! "$PY" -c 'import struct' >/dev/null 2>&1; then
    echo "SKIP: no Python interpreter to write the test env map (set PYTHON=/path/to/python)"
    exit 77
fi

if ! command -v pkg-config >/dev/null 2>&1 || ! pkg-config --exists stb; then
    echo "SKIP: the example reads .hdr files with stb_image, which is not installed (apt-get install libstb-dev)"
    exit 77
fi

TMP=$(mktemp -d "${TMPDIR:-/tmp}/penumbra-example.XXXXXX") || exit 1
cleanup() {
    if [ "${KEEP_TMP:-0}" = 1 ]; then
        echo "kept $TMP"
    else
        rm -rf "$TMP"
    fi
}
trap cleanup EXIT

passed=0
failed=0
pass() { passed=$((passed + 1)); echo "ok: $1"; }
fail() { failed=$((failed + 1)); echo "FAIL: $1"; }
finish() {
    echo "$passed passed, $failed failed"
    [ "$failed" -eq 0 ] && exit 0 || exit 1
}

PREFIX=$TMP/prefix
GENERATOR=()
if command -v ninja >/dev/null 2>&1; then
    GENERATOR=(-G Ninja)
fi

# 1. Install.
if cmake --install "$BUILD_DIR" --prefix "$PREFIX" >"$TMP/install.log" 2>&1; then
    pass "cmake --install $BUILD_DIR --prefix PREFIX"
else
    cat "$TMP/install.log"
    fail "cmake --install"
    finish
fi

# 2. Configure and build examples/ against the installed package.
if cmake -S "$SOURCE_DIR/examples" -B "$TMP/build" "${GENERATOR[@]}" -DCMAKE_PREFIX_PATH="$PREFIX" \
        -DPENUMBRA_EXAMPLES_WERROR=ON -DCMAKE_C_FLAGS="$EXTRA_FLAGS" -DCMAKE_EXE_LINKER_FLAGS="$EXTRA_FLAGS" \
        >"$TMP/configure.log" 2>&1 &&
    cmake --build "$TMP/build" >"$TMP/build.log" 2>&1; then
    pass "examples/ configure and build with find_package(penumbra) (-Wall -Wextra -Werror)"
else
    cat "$TMP/configure.log" "$TMP/build.log" 2>/dev/null
    fail "examples/ configure and build"
    finish
fi
if grep -q "$PREFIX" "$TMP/build/CMakeCache.txt" && grep -q "penumbra_DIR:PATH=$PREFIX" "$TMP/build/CMakeCache.txt"; then
    pass "find_package found the temporary prefix"
else
    fail "find_package(penumbra) did not resolve to $PREFIX: $(grep penumbra_DIR "$TMP/build/CMakeCache.txt")"
fi

# 3. A small env map: a sky gradient with a bright spot, 32x16, Radiance .hdr (flat RGBE scanlines, top row first).
ENV=$TMP/env.hdr
if "$PY" - "$ENV" <<'EOF'
import math, sys
w, h = 32, 16
out = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (h, w))
for y in range(h):  # top row first
    v = (y + 0.5) / h
    for x in range(w):
        u = (x + 0.5) / w
        sky = max(0.0, 1.0 - v)
        rgb = [0.2 + 0.3 * sky, 0.3 + 0.4 * sky, 0.5 + 0.5 * sky]
        if abs(u - 0.25) < 0.07 and abs(v - 0.3) < 0.1:
            rgb = [rgb[0] + 20.0, rgb[1] + 18.0, rgb[2] + 15.0]
        mant, e = math.frexp(max(rgb))
        out += bytes([min(255, int(c * 256.0 / 2.0 ** e)) for c in rgb] + [e + 128])
open(sys.argv[1], "wb").write(out)
EOF
then
    pass "wrote a test env map"
else
    fail "writing the env map with $PY"
    finish
fi

# 4. Run the example and check its output.
OUT=$TMP/out/render.pfm
mkdir -p "$TMP/out"
if "$TMP/build/render_scene" "$ENV" "$OUT" 64 48 >"$TMP/run.log" 2>&1; then
    pass "render_scene ENV OUT 64 48"
else
    cat "$TMP/run.log"
    fail "render_scene exited with an error"
    finish
fi
check_pfm() { # FILE WIDTH HEIGHT
    "$PY" - "$@" <<'EOF'
import math, struct, sys
path, w, h = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
data = open(path, "rb").read()
header = b"PF\n%d %d\n-1.0\n" % (w, h)
if not data.startswith(header):
    sys.exit("bad header: %r" % data[:32])
body = data[len(header):]
if len(body) != w * h * 12:
    sys.exit("body has %d bytes, expected %d" % (len(body), w * h * 12))
px = struct.unpack("<%df" % (w * h * 3), body)
if not all(math.isfinite(v) and v >= 0 for v in px):
    sys.exit("non-finite or negative pixels")
if max(px) <= 0:
    sys.exit("the image is black")
# PFM rows are bottom-to-top: the last stored row is the top of the image, which sees the sky only.
top = px[(h - 1) * w * 3:]
bottom = px[:w * 3]
if not (sum(top) > 0 and sum(bottom) > 0):
    sys.exit("empty top or bottom row")
EOF
}
if [ -f "$OUT" ] && msg=$(check_pfm "$OUT" 64 48 2>&1); then
    pass "output exists and is a 64x48 RGB PFM with finite, non-negative pixels"
else
    fail "output check: ${msg:-missing $OUT}"
fi
if [ -z "$(find "$TMP/out" -name '*.tmp')" ]; then
    pass "no temporary file left beside the output"
else
    fail "temporary files left: $(find "$TMP/out" -name '*.tmp')"
fi
if "$TMP/build/render_scene" "$ENV" "$TMP/out/default.pfm" >/dev/null 2>&1 && msg=$(check_pfm "$TMP/out/default.pfm" 160 120 2>&1); then
    pass "default size is 160x120"
else
    fail "default-size render: ${msg:-render_scene failed}"
fi
# The same scene with FIV shadows: the C-only bake-and-render path; the box's
# shadow makes the image darker than the unshadowed one, never brighter.
if "$TMP/build/render_scene" "$ENV" "$TMP/out/fiv.pfm" 64 48 fiv >"$TMP/fiv.log" 2>&1 && msg=$(check_pfm "$TMP/out/fiv.pfm" 64 48 2>&1); then
    if "$PY" - "$OUT" "$TMP/out/fiv.pfm" <<'EOF'
import struct, sys
def pixels(path):
    data = open(path, "rb").read()
    body = data.split(b"\n", 3)[3]
    return struct.unpack("<%df" % (len(body) // 4), body)
plain, shadowed = pixels(sys.argv[1]), pixels(sys.argv[2])
darker = sum(1 for a, b in zip(plain, shadowed) if b < a - 1e-4)
brighter = sum(1 for a, b in zip(plain, shadowed) if b > a + 1e-4)
if darker < 50 or brighter:
    sys.exit("fiv image: %d darker and %d brighter values than unshadowed" % (darker, brighter))
EOF
    then
        pass "render_scene ... fiv bakes the box's field in C and darkens its shadow"
    else
        fail "fiv render is not a shadowed version of the unshadowed one"
    fi
else
    fail "render_scene ... fiv: ${msg:-$(tail -3 "$TMP/fiv.log")}"
fi
# Errors are reported, not crashed on.
printf 'PF\n1 1\n-1.0\n\0\0\0\0\0\0\0\0\0\0\0\0' >"$TMP/not.pfm"
if "$TMP/build/render_scene" "$TMP/not.pfm" "$TMP/out/x.pfm" >"$TMP/err.log" 2>&1; then
    fail "a non-HDR input was accepted"
elif [ -e "$TMP/out/x.pfm" ]; then
    fail "a failed run left an output file"
elif grep -q "not a Radiance .hdr file" "$TMP/err.log"; then
    pass "a non-HDR input is refused with a message: $(head -c 200 "$TMP/err.log")"
else
    fail "unexpected error output for a non-HDR input: $(cat "$TMP/err.log")"
fi
if "$TMP/build/render_scene" "$TMP/missing.hdr" "$TMP/out/y.pfm" >"$TMP/err.log" 2>&1; then
    fail "a missing env map was accepted"
elif grep -q "cannot open" "$TMP/err.log"; then
    pass "a missing env map is reported: $(head -c 200 "$TMP/err.log")"
else
    fail "unexpected error output for a missing env map: $(cat "$TMP/err.log")"
fi

# 5. pkg-config.
if ! command -v pkg-config >/dev/null 2>&1; then
    echo "SKIP: pkg-config is not installed; the penumbra.pc checks did not run"
    finish
fi
PC_DIR=$(dirname "$(find "$PREFIX" -name penumbra.pc | head -n 1)")
if [ ! -f "$PC_DIR/penumbra.pc" ]; then
    fail "no penumbra.pc under $PREFIX"
    finish
fi
if flags=$(PKG_CONFIG_PATH=$PC_DIR pkg-config --cflags --libs penumbra 2>"$TMP/pc.log"); then
    pass "pkg-config --cflags --libs penumbra: $flags"
else
    fail "pkg-config --cflags --libs penumbra: $(cat "$TMP/pc.log")"
    finish
fi
# -I and -L may be spelt relative to the .pc file (${pcfiledir}/../..): compare resolved paths.
want_inc=$(cd "$PREFIX/include" && pwd -P)
want_lib=$(cd "$PC_DIR/.." && pwd -P)
inc_ok=0
lib_ok=0
for word in $flags; do
    case $word in
    -I*) [ -d "${word#-I}" ] && [ "$(cd "${word#-I}" && pwd -P)" = "$want_inc" ] && inc_ok=1 ;;
    -L*) [ -d "${word#-L}" ] && [ "$(cd "${word#-L}" && pwd -P)" = "$want_lib" ] && lib_ok=1 ;;
    esac
done
if [ $inc_ok = 1 ] && [ $lib_ok = 1 ]; then
    pass "pkg-config flags point into the install prefix"
else
    fail "pkg-config flags do not point into the install prefix $PREFIX (penumbra.pc says: $(grep '^prefix=' "$PC_DIR/penumbra.pc"))"
fi
# shellcheck disable=SC2086 # the flags are a list of words
if cc -std=c99 -Wall -Wextra -Werror $EXTRA_FLAGS $(PKG_CONFIG_PATH=$PC_DIR pkg-config --cflags penumbra stb) \
        "$SOURCE_DIR/examples/render_scene.c" -o "$TMP/render_scene_pc" \
        $(PKG_CONFIG_PATH=$PC_DIR pkg-config --libs penumbra stb) -Wl,-rpath,"$(cd "$PC_DIR/.." && pwd)" \
        >"$TMP/cc.log" 2>&1; then
    pass "examples/render_scene.c compiles and links with the pkg-config flags"
    if "$TMP/render_scene_pc" "$ENV" "$TMP/out/pc.pfm" 64 48 >/dev/null 2>&1 && cmp -s "$OUT" "$TMP/out/pc.pfm"; then
        pass "the pkg-config build renders the same image as the CMake build"
    else
        fail "the pkg-config build failed to run or rendered a different image"
    fi
else
    cat "$TMP/cc.log"
    fail "compiling examples/render_scene.c with the pkg-config flags"
fi
finish
