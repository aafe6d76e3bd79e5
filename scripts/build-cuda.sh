#!/usr/bin/env bash
# Builds `fusiondet` with burn's CUDA backend (cargo feature `cuda`) without network access.
#
#   scripts/build-cuda.sh                 # release build of the CLI into $CARGO_TARGET_DIR
#   scripts/build-cuda.sh cargo test ...  # any other command, run with the same environment
#
# Why this is needed: burn-cuda depends on cubecl-cuda, which always links cubecl-llvm. Its
# build dependency tracel-llvm-bundler downloads a prebuilt LLVM 23.1 archive from GitHub in
# its build script and fails without network. The bundler skips the download when its install
# directory already carries a marker file, and it only reads that directory through
# `bin/llvm-config`, so a distribution LLVM (Debian's LLVM 22) can stand in for it. The CUDA
# kernels themselves are compiled by NVRTC at run time (cubecl-cuda's `cpp` feature, turned on
# by our `cuda` feature), so LLVM only has to link, not to generate code.
#
# Environment (all optional):
#   CARGO_TARGET_DIR  build directory (default: target-cuda in the repository)
#   LLVM_MAJOR        Debian LLVM version to stand in for the bundle (default: 22)
#   XDG_DATA_HOME     where the bundler looks for its LLVM (default: ~/.local/share)
#   CUDARC_CUDA_VERSION  CUDA API version to bind, e.g. 12080; without it and without nvcc,
#                     cudarc binds the newest it knows (13.4) and loads the driver at run time.
#   EMBED_MODELS      0 to leave the shipped models out of the binary (125 MB of weights), so
#                     that it fits a call to a lent GPU machine; scripts/gpu-check.sh reads
#                     the models from disk anyway (default: 1, as the CPU build)
# Idempotent: installed packages, links and the marker are checked before being made.
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"

llvm_major="${LLVM_MAJOR:-22}"
llvm_prefix="/usr/lib/llvm-${llvm_major}"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$repo/target-cuda}"

# 1. Debian packages: LLVM's static libraries, headers and llvm-config (llvm-N-dev), Polly,
#    which Debian's llvm-config lists among the static libraries (libpolly-N-dev), zstd and
#    zlib, which it lists among the system libraries (z3 and libxml2 come with llvm-N-dev),
#    and g++ for cubecl-llvm's C++ shims. On bookworm, llvm-22 comes from bookworm-security.
#    Installed only when missing.
packages=("llvm-${llvm_major}-dev" "libpolly-${llvm_major}-dev" "libzstd-dev" "zlib1g-dev" "g++")
missing=()
for p in "${packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
if ((${#missing[@]})); then
    sudo=()
    if [ "$(id -u)" -ne 0 ]; then sudo=(sudo); fi
    echo "installing ${missing[*]}"
    "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -q
    "${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
fi
llvm_config="$llvm_prefix/bin/llvm-config"
[ -x "$llvm_config" ] || { echo "error: $llvm_config not found" >&2; exit 1; }

# 2. The bundler's install directory: $XDG_DATA_HOME (or ~/.local/share), then
#    tracel/tracel-llvm-<version>-<release>, as in tracel-llvm-bundler 23.1.0-4's config.rs.
#    bin, include and lib point into Debian's LLVM; the marker file tells the bundler the
#    archive is already unpacked, so its build script returns before any download. A real
#    bundle found there (bin is a directory, not our link) is left as it is.
bundle="${XDG_DATA_HOME:-$HOME/.local/share}/tracel/tracel-llvm-23.1.0-4"
if [ -d "$bundle/bin" ] && [ ! -L "$bundle/bin" ]; then
    echo "using the LLVM bundle already unpacked in $bundle"
else
    # Only what is missing is made: the bundler reruns (and everything above cubecl-llvm
    # rebuilds) when the marker's timestamp changes.
    mkdir -p "$bundle"
    for d in bin include lib; do
        if [ "$(readlink "$bundle/$d" || true)" != "$llvm_prefix/$d" ]; then
            ln -sfn "$llvm_prefix/$d" "$bundle/$d"
        fi
    done
    [ -e "$bundle/.tracel-llvm-installed" ] || touch "$bundle/.tracel-llvm-installed"
fi

# 3. Link shims. The bundler passes each system library that llvm-config names as
#    `-l<file stem>`, so Debian's `/usr/lib/.../libz3.so` becomes `-llibz3`, which the linker
#    looks up as `liblibz3.so`. A `lib<stem>.so` link to every such path, in a directory on
#    LIBRARY_PATH (read by the cc that links), resolves it.
shims="$CARGO_TARGET_DIR/llvm-link-shims"
mkdir -p "$shims"
for lib in $("$bundle/bin/llvm-config" --link-static --system-libs); do
    case "$lib" in
    /*.so)
        stem="$(basename "$lib" .so)"
        [ "$(readlink "$shims/lib$stem.so" || true)" = "$lib" ] || ln -sfn "$lib" "$shims/lib$stem.so"
        ;;
    esac
done
export LIBRARY_PATH="$shims${LIBRARY_PATH:+:$LIBRARY_PATH}"

# 4. The build itself, from the vendored registry only (Cargo.lock already holds every crate
#    of the CUDA graph), or the command given on the command line.
if (($#)); then
    exec "$@"
fi
if [[ "${EMBED_MODELS:-1}" == 0 ]]; then
    cargo build --release --locked --offline -p fusiondet --no-default-features --features cuda
else
    cargo build --release --locked --offline -p fusiondet --features cuda
fi

# 5. What was built: its size as built, stripped and (when zstd is here) compressed, and the
#    shared libraries it needs at load time. The CUDA driver (libcuda) and NVRTC are not among
#    them: they are opened at run time, so the binary starts on machines without them.
bin="$CARGO_TARGET_DIR/release/fusiondet"
stripped="$(mktemp)"
trap 'rm -f "$stripped" "$stripped.zst"' EXIT
strip -o "$stripped" "$bin"
echo "binary:   $bin"
echo "size:     $(stat -c %s "$bin") bytes as built, $(stat -c %s "$stripped") bytes stripped"
if command -v zstd >/dev/null; then
    zstd -q -19 -f "$stripped" -o "$stripped.zst"
    echo "zstd -19: $(stat -c %s "$stripped.zst") bytes (stripped)"
fi
echo "ldd:"
ldd "$bin"
