#!/bin/sh
# Screenshots of `fusiondet view` pages in headless Chromium (Debian: apt-get install chromium),
# to look at a page without a display, and as the browser test does.
#   scripts/view-screenshot.sh PAGE.html OUT.png [WIDTHxHEIGHT] [VIEW]
# VIEW: empty for the page's default view, `bev` for the bird's-eye view (`#bev` in the
# address). With `probe` in VIEW (`probe-bev`), the page lays itself out at a fixed height
# and records where it drew the boxes and points (`<pre id="probe">`, which `--dump-dom`
# prints): what the browser test compares with the screenshot's pixels.
# Flags: no sandbox (root in containers), software WebGL (SwiftShader; no GPU needed), no
# background networking (nothing may reach the network), a throwaway profile, and virtual
# time, so the page has loaded and drawn before the screenshot is taken.
set -eu
page=$1
out=$2
size=${3:-1400x800}
view=${4:-}
browser=${CHROMIUM:-$(command -v chromium || command -v chromium-browser || command -v google-chrome || true)}
if [ -z "$browser" ]; then
  echo "no Chromium found (install Debian's chromium, or set CHROMIUM=/path/to/it)" >&2
  exit 2
fi
profile=$(mktemp -d)
trap 'rm -rf "$profile"' EXIT
abs=$(cd "$(dirname "$page")" && pwd)/$(basename "$page")
"$browser" --headless --no-sandbox --disable-gpu --enable-unsafe-swiftshader \
  --use-angle=swiftshader --disable-quic --no-first-run --disable-background-networking \
  --disable-component-update --disable-sync --disable-dev-shm-usage --hide-scrollbars \
  --user-data-dir="$profile" --window-size="$(echo "$size" | tr x ,)" \
  --virtual-time-budget=10000 --screenshot="$out" "file://$abs#$view" 2>/dev/null
