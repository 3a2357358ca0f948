#!/usr/bin/env bash
# Builds the image `renderfarm:local` without any registry: release binaries built on this host
# (stripped) go into a base image made here, `renderfarm-base:local`, that holds only the shared
# libraries they need (found with ldd), a passwd entry for the unprivileged user 10001, /tmp and
# /data. Run from anywhere; reuses binaries that are already built.
set -euo pipefail
cd "$(dirname "$0")/.."
build=deploy/.build
echo "== binaries"
cargo build --release -p coordinator -p worker --bins
rm -rf "$build"
mkdir -p "$build/rootfs"
for bin in coordinator worker; do
    strip -o "deploy/prebuilt/$bin" "target/release/$bin"
done

echo "== base image renderfarm-base:local (from this host's libraries)"
rootfs="$build/rootfs"
# No /data here: the Dockerfile's COPY --chown creates it owned by the image's user.
mkdir -p "$rootfs/etc" "$rootfs/tmp"
chmod 1777 "$rootfs/tmp"
libs=$(ldd deploy/prebuilt/coordinator deploy/prebuilt/worker | awk '$2 == "=>" && $3 ~ /^\// {print $3} $1 ~ /^\// {print $1}' | sort -u)
for lib in $libs; do
    mkdir -p "$rootfs$(dirname "$lib")"
    cp -L "$lib" "$rootfs$lib"
done
printf 'root:x:0:0:root:/root:/sbin/nologin\nfarm:x:10001:10001:render farm:/data:/sbin/nologin\n' > "$rootfs/etc/passwd"
printf 'root:x:0:\nfarm:x:10001:\n' > "$rootfs/etc/group"
printf 'hosts: files dns\n' > "$rootfs/etc/nsswitch.conf"
tar --numeric-owner --owner=0 --group=0 -C "$rootfs" -c . | docker import - renderfarm-base:local >/dev/null

echo "== image renderfarm:local"
docker build -q -f deploy/Dockerfile --target host \
    --build-arg RUNTIME=renderfarm-base:local -t renderfarm:local . >/dev/null
docker image ls renderfarm:local --format 'renderfarm:local {{.Size}}'
