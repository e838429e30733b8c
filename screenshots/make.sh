#!/usr/bin/env bash
# Regenerates screenshots/*.png from the real window under Xvfb (software rendering), one per
# committed session file. Sessions are written by:
#   cargo test --test gui -- --ignored write_screenshot_sessions
# Needs: xvfb, xauth, imagemagick (import), mesa-vulkan-drivers; xdotool (optional) moves the
# pointer out of the way.
set -euo pipefail
cd "$(dirname "$0")/.."
# MLOD_BIN=path uses that binary instead of building the release one.
bin="${MLOD_BIN:-target/release/mlod}"
[ -n "${MLOD_BIN:-}" ] || cargo build --release
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
for s in screenshots/*.session.json; do
  name=$(basename "$s" .session.json)
  xvfb-run -a -s "-screen 0 1280x800x24" sh -c "
    $bin gui --session '$s' >/dev/null 2>&1 &
    pid=\$!
    sleep \${MLOD_SHOT_WAIT:-10}   # the failure browser scans the scene on load
    command -v xdotool >/dev/null && xdotool mousemove 1275 795 && sleep 1   # no hover tooltip
    import -window root 'screenshots/$name.png'
    kill \$pid"
  echo "wrote screenshots/$name.png"
done
# The README's before/after of online calibration, side by side.
# The viewports only (the panels cropped), a grey bar between them.
convert \( screenshots/calibration_before.png -crop 680x750+270+25 +repage \) \( -size 6x750 xc:'#9aa0a6' \) \
  \( screenshots/calibration_after.png -crop 680x750+270+25 +repage \) +append screenshots/calibration.png
echo "wrote screenshots/calibration.png"
# The README's real Argoverse 2 sweep at α = 0.04 coloured by tr(Ξ), before and after ICP.
convert \( screenshots/av2_trace.png -crop 700x685+230+90 +repage \) \( -size 6x685 xc:'#9aa0a6' \) \
  \( screenshots/av2_icp.png -crop 700x685+230+90 +repage \) +append screenshots/av2.png
echo "wrote screenshots/av2.png"
