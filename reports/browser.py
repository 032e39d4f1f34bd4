"""The report as a reader sees it: open the page in headless Chromium (Playwright, offline) and
check that it works, with screenshots.

Checked: no console or page errors; Table 1 (the silhouette-IoU tables, test and dev) has a row for
every expected label; every picture decoded; every <model-viewer> loaded its model. Chromium is
Debian's (``/usr/bin/chromium``); WebGL runs on SwiftShader, so no GPU is needed.
"""
from __future__ import annotations

import io
import json
import time
from pathlib import Path

from ipm.io.paths import shown_path

CHROMIUM = "/usr/bin/chromium"
"""The browser Playwright drives (never downloaded)."""
ARGS = ("--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--no-sandbox")
"""WebGL without a GPU (SwiftShader); no sandbox, so it also runs as root in a container."""
MODEL_TIMEOUT_S = 60.0
"""How long all 3D views together may take to load."""
MAX_SHOT_PX = 60000
"""The full-page screenshot stops at this height."""
SLICE_PX = 4000
"""Height of one capture of the full-page screenshot."""

_IMAGES = """() => Array.from(document.images).map((im, i) => ({
  i, ok: im.complete && im.naturalWidth > 0, alt: im.alt || "",
  where: (im.closest("[id]") || {}).id || ""}))"""
_ROWS = """() => Array.from(document.querySelectorAll('table.table1 tbody th[scope=row]'))
  .map(th => th.dataset.label || th.textContent.trim())"""
_MODELS = """async (timeoutMs) => {
  const views = Array.from(document.querySelectorAll("model-viewer"));
  if (views.length && !customElements.get("model-viewer")) {
    return views.map((v, i) => ({i, alt: v.alt || "", ok: false, why: "<model-viewer> is not defined"}));
  }
  views.forEach(v => { const d = v.closest("details"); if (d) d.open = true; v.loading = "eager"; });
  return Promise.all(views.map((v, i) => new Promise(resolve => {
    const done = (ok, why) => resolve({i, alt: v.alt || "", ok, why});
    if (v.loaded) return done(true, "");
    v.addEventListener("load", () => done(true, ""), {once: true});
    v.addEventListener("error", e => done(false, "error event: " + JSON.stringify((e.detail || {}).type || "")),
                       {once: true});
    setTimeout(() => done(v.loaded, v.loaded ? "" : "timed out"), timeoutMs);
  })));
}"""


def check_report(html: str, out_dir: str, expected_rows: list[str]) -> dict:
    """Open ``html`` in headless Chromium, check it (module docstring) and write screenshots
    (``page.png``, ``table1.png``, ``model.png`` when the page has a 3D view) and ``check.json``
    into ``out_dir``; return what ``check.json`` holds. Raise ``RuntimeError`` (one line) if
    anything failed."""
    from playwright.sync_api import sync_playwright

    path = Path(html).resolve()
    if not path.is_file():
        raise RuntimeError(f"report check: {html} does not exist")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    errors: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=list(ARGS))
        try:
            page = browser.new_page(viewport={"width": 1360, "height": 900})
            page.on("console", lambda m: errors.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(f"page error: {e}"))
            page.route("**/*", lambda route: route.abort() if not route.request.url.startswith(("file:", "data:"))
                       else route.continue_())  # offline: the page must need nothing from the network
            page.goto(path.as_uri(), wait_until="load", timeout=120_000)
            rows = list(dict.fromkeys(page.evaluate(_ROWS)))
            images = page.evaluate(_IMAGES)
            models = page.evaluate(_MODELS, MODEL_TIMEOUT_S * 1000)
            shots = _screenshots(page, out, any(m["ok"] for m in models))
        finally:
            browser.close()
    missing = [r for r in expected_rows if r not in rows]
    broken = [im for im in images if not im["ok"]]
    failed = [m for m in models if not m["ok"]]
    result = {"html": shown_path(html), "seconds": round(time.monotonic() - start, 1), "errors": errors,
              "rows_found": rows, "rows_missing": missing, "images_ok": len(images) - len(broken),
              "images_broken": broken, "models_loaded": len(models) - len(failed), "models_failed": failed,
              "screenshots": shots}
    (out / "check.json").write_text(json.dumps(result, indent=1) + "\n")
    problems = []
    if errors:
        problems.append(f"{len(errors)} console/page error(s), first: {errors[0]}")
    if missing:
        problems.append(f"Table 1 lacks row(s) {', '.join(missing)}")
    if broken:
        problems.append(f"{len(broken)} image(s) did not load (first in #{broken[0]['where']}: "
                        f"{broken[0]['alt'] or 'no alt'})")
    if failed:
        problems.append(f"{len(failed)} 3D view(s) did not load (first: {failed[0]['alt']}: {failed[0]['why']})")
    if problems:
        raise RuntimeError(f"report check of {html} failed: {'; '.join(problems)} (details: {out / 'check.json'})")
    return result


def _screenshots(page, out: Path, with_model: bool) -> list[str]:
    """The whole page, Table 1 (the test split beside the paper's) and the first loaded 3D view."""
    _full_page(page, out / "page.png")
    names = ["page.png"]
    table = page.locator("#table1 .side")
    if table.count():
        table.first.screenshot(path=str(out / "table1.png"))
        names.append("table1.png")
    if with_model:
        index = page.evaluate("Array.from(document.querySelectorAll('model-viewer')).findIndex(v => v.loaded)")
        view = page.locator("model-viewer").nth(index)
        view.scroll_into_view_if_needed()
        page.wait_for_timeout(1500)  # a few frames on SwiftShader
        view.screenshot(path=str(out / "model.png"))
        names.append("model.png")
    return names


def _full_page(page, path: Path) -> None:
    """The page from the top, up to :data:`MAX_SHOT_PX` high, captured in slices (one capture
    taller than SwiftShader's largest texture, 8192 px, repeats the top of the page) and stitched."""
    from PIL import Image

    width = page.evaluate("document.documentElement.scrollWidth")
    height = min(page.evaluate("document.documentElement.scrollHeight"), MAX_SHOT_PX)
    sheet = Image.new("RGB", (width, height), "white")
    for y in range(0, height, SLICE_PX):
        clip = {"x": 0, "y": y, "width": width, "height": min(SLICE_PX, height - y)}
        sheet.paste(Image.open(io.BytesIO(page.screenshot(clip=clip, full_page=True))).convert("RGB"), (0, y))
    sheet.save(path)  # zlib's default level (optimize=True: three times as long for a file 2 % smaller)
