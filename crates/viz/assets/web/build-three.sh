#!/bin/sh
# Rebuilds three.bundle.min.js, the viewer's vendored three.js, from the npm registry:
# three 0.187.0 (tree-shaken to what three-entry.js names) with esbuild 0.28.2.
# Run from anywhere; needs node and npm. The result is committed, so neither a build nor
# a page needs the network.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
npm init -y >/dev/null
npm install --no-audit --no-fund --silent three@0.187.0 esbuild@0.28.2
cp "$here/three-entry.js" .
npx esbuild three-entry.js --bundle --minify --format=iife --global-name=FusionThree \
  --legal-comments=none --target=es2020 --outfile="$here/three.bundle.min.js"
cp node_modules/three/LICENSE "$here/THREE-LICENSE"
