# Sourced by setup.sh: have_llvm [DIR...] succeeds if a shared libLLVM 16 or newer is in
# one of the DIRs (default: the usual system library folders).
have_llvm() {
    local d f
    [ "$#" -gt 0 ] || set -- /usr/lib/x86_64-linux-gnu /usr/lib/aarch64-linux-gnu /usr/lib64 /usr/lib /usr/local/lib
    for d in "$@"; do
        # An unmatched pattern stays as written and fails the -e test.
        for f in "$d"/libLLVM-1[6-9]*.so* "$d"/libLLVM-[2-9][0-9]*.so* \
            "$d"/libLLVM.so.1[6-9]* "$d"/libLLVM.so.[2-9][0-9]*; do
            [ -e "$f" ] && return 0
        done
    done
    return 1
}
