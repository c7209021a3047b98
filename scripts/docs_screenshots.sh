#!/usr/bin/env bash
# Build the docs (Sphinx, warnings as errors) into a temporary folder and screenshot the getting-started and tasks
# pages (first screen and whole page) with headless Chromium; needs Debian's `chromium` (apt-get install chromium).
set -euo pipefail

out=${1:-/tmp/docs-shots}
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
python=$root/.venv/bin/python
width=1280
screen=2400

command -v chromium >/dev/null || { echo "chromium not found: apt-get install -y --no-install-recommends chromium" >&2; exit 1; }
"$python" -c "import sphinx, myst_parser, furo" 2>/dev/null \
    || { echo "the docs stack is missing from .venv: make docs (or pip install -c constraints.txt -r docs/requirements.txt)" >&2; exit 1; }

html=$(mktemp -d /tmp/docs-html.XXXXXX)
trap 'rm -rf "$html"' EXIT
mkdir -p "$out"

(cd "$root" && nice -n 19 "$python" -m sphinx -W --keep-going -q -b html docs "$html") >&2

shoot() {  # shoot URL HEIGHT PNG
    nice -n 19 chromium --headless=new --no-sandbox --disable-gpu --hide-scrollbars --window-size="$width,$2" \
        --screenshot="$3" "$1" >/dev/null 2>&1 || true
    [[ -s $3 ]] || { echo "chromium wrote no $3" >&2; exit 1; }
    echo "$3"
}

page_height() {  # page_height PAGE.html: the laid-out page's height in CSS pixels at the screenshot width
    local probe=$html/${1%.html}.__height.html
    sed 's#</body>#<script>addEventListener("load",()=>document.body.setAttribute("data-page-height",Math.ceil(document.documentElement.scrollHeight)))</script></body>#' \
        "$html/$1" >"$probe"
    nice -n 19 chromium --headless=new --no-sandbox --disable-gpu --hide-scrollbars --window-size="$width,$screen" \
        --virtual-time-budget=3000 --dump-dom "file://$probe" 2>/dev/null \
        | grep -o 'data-page-height="[0-9]*"' | grep -o '[0-9]*' || echo 6000
    rm -f "$probe"
}

for page in getting-started tasks; do
    [[ -f $html/$page.html ]] || { echo "no $page.html in the build" >&2; exit 1; }
    shoot "file://$html/$page.html" "$screen" "$out/$page.png"
    height=$(page_height "$page.html")
    if (( height > screen )); then
        shoot "file://$html/$page.html" "$height" "$out/$page-full.png"
    fi
done
