#!/usr/bin/env bash
# Vendor three.js from the npm registry into backends/web/vendor/three/ (the live page ships it: no CDN).
#
#   scripts/vendor_three.sh [VERSION]      (default: the version in backends/web/vendor/three/VERSION)
#
# Copies the ES module build (three.module.js and the three.core.js it imports), the glTF loader
# and the two utilities it imports, and the licence.
set -euo pipefail
cd "$(dirname "$0")/.."
dest=backends/web/vendor/three
version=${1:-$(cat "$dest/VERSION")}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$work" && npm pack --silent "three@$version" >/dev/null && tar xzf "three-$version.tgz")
pkg=$work/package
mkdir -p "$dest/addons/loaders" "$dest/addons/utils"
cp "$pkg/build/three.module.js" "$pkg/build/three.core.js" "$pkg/LICENSE" "$dest/"
cp "$pkg/examples/jsm/loaders/GLTFLoader.js" "$dest/addons/loaders/"
cp "$pkg/examples/jsm/utils/BufferGeometryUtils.js" "$pkg/examples/jsm/utils/SkeletonUtils.js" "$dest/addons/utils/"
echo "$version" > "$dest/VERSION"
echo "vendored three.js $version into $dest"
