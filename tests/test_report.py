"""Snakemake's HTML report, opened in headless Chromium the way a reader goes through it: the landing page, then
every category, subcategory and item, each item opened with its eye button. Every image must have decoded, every
video (a gallery episode: an MP4 inside a page of its own, ocpipe.util.video_page) must have loaded its metadata,
no caption may carry a docutils error, and the page must load nothing from the network.

The browser is Debian's `chromium` and `chromium-driver` (bin/setup.sh installs them); without them the tests
skip, except under CI (CI=true), where they fail. OCPIPE_REPORT_SCREENSHOT=path.png saves the tiny run's gallery page
for docs/; OCPIPE_REPORT=path/report.html checks a report a run built (and screenshots its gallery page instead)."""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from conftest import REPO, TINY_TARGETS, snakemake
from PIL import Image

from ocpipe.bookkeeping import report_page
from ocpipe.study import registry
from ocpipe.study import report as study_report
from ocpipe.util import video_page

BROWSER = ("chromium", "chromium-browser", "google-chrome")
LOCAL_SCHEMES = ("data:", "file:", "blob:", "about:")  # everything else is a load from the network
WAIT_S = 120  # how long a page or a video may take to load on a busy machine before the test gives up on it


def render(rst: str, tmp_path: Path) -> str:
    """``rst`` as Snakemake renders a caption (docutils' HTML body), with the project's directives, in ``tmp_path``."""
    from docutils.core import publish_parts

    report_page.register(REPO)
    cwd = os.getcwd()
    os.chdir(tmp_path)  # Snakemake renders in the workdir: the directives' paths are relative to it
    try:
        return publish_parts(rst, writer="html")["html_body"]
    finally:
        os.chdir(cwd)


def test_a_table_directive_shows_the_study_writers_markdown_as_an_html_table(tmp_path):
    frame = pl.DataFrame({"Method": ["Pure *Visual*", "2D"], "SR mean": [0.25, 0.00001], "Claim": ["a < b", "`x`_"]})
    study_report.write(frame, tmp_path / "t.csv", tmp_path / "t.md", "Table 9.9: a test", "Profile x. Rows differ.")
    html = render(".. ocpipe-table:: t.md\n", tmp_path)
    assert "<caption>Table 9.9: a test</caption>" in html and re.search(r"<th[^>]*>(<p>)?SR mean<", html)
    # a claim's characters stay text, never markup: no emphasis, no link, no docutils error
    assert "Pure *Visual*" in html and "a &lt; b" in html and "`x`_" in html and "system-message" not in html
    assert "1.0e-05" in html and "<em>Profile x. Rows differ.</em>" in html and "literal\">t.md<" in html
    (tmp_path / "two.md").write_text("**First**\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\nPass: pass.\n\n"
                                     "**Second**\n\n| c |\n|---|\n| 3 |\n")
    html = render(".. ocpipe-table:: two.md\n", tmp_path)
    assert html.count("<table") == 2 and "<caption>Second</caption>" in html and "<em>Pass: pass.</em>" in html


def test_a_table_directive_names_a_missing_file_and_refuses_a_malformed_one(tmp_path):
    html = render(".. ocpipe-table:: results/tables/table5_1.md\n   :missing: build it with ``snakemake``\n",
                  tmp_path)
    assert "results/tables/table5_1.md" in html and "build it with ``snakemake``" in html
    (tmp_path / "bad.md").write_text("**T**\n\n| a | b |\n|---|---|\n| 1 | 2 | 3 |\n")
    with pytest.raises(ValueError, match=r"bad.md, line 5: 3 cells under a header of 2"):
        report_page.read_markdown(tmp_path / "bad.md")
    (tmp_path / "torn.md").write_text("**T**\n\n| a | b |\n| 1 | 2 |\n")
    with pytest.raises(ValueError, match=r"torn.md, line 3: a table needs a header row, a '\|---\|' row"):
        report_page.read_markdown(tmp_path / "torn.md")


def test_the_commit_directive_names_the_checkout_or_says_it_is_none(tmp_path):
    assert "Report built by the workflow at commit" in render(".. ocpipe-commit::\n", tmp_path)
    report_page.register(tmp_path)  # not a git checkout
    from docutils.core import publish_parts

    html = publish_parts(".. ocpipe-commit::\n", writer="html")["html_body"]
    # the text, whatever spans a docutils release wraps a literal's words in
    assert f"unknown ({tmp_path} is not a git checkout)" in re.sub(r"<[^>]+>", "", html)


def test_every_table_and_figure_has_a_group_and_one_label():
    groups = {report_page.group(scope) for scope in registry.SCOPES}
    for table in registry.TABLES:
        assert report_page.table_group(table) in groups
        assert list(report_page.table_label(table)) == ["table"]  # one label: Snakemake makes a second a switch
    for figure in [*registry.SPATIAL_FIGURES, *registry.FIGURES]:
        assert report_page.figure_group(figure) in groups and list(report_page.figure_label(figure)) == ["figure"]
    assert report_page.group("main") == "Main job: Tables 5.1-5.2"
    assert report_page.table_label("table5_10") == {"table": registry.TABLES["table5_10"].title[len("Table "):]}
    assert report_page.findings_group("findings") == report_page.WHOLE_STUDY
    assert report_page.findings_label("findings_stackcube") == {"table": "findings 11-12, judged on this build"}


@pytest.fixture(scope="module")
def browser():
    missing = []
    binary = next((path for path in map(shutil.which, BROWSER) if path), None)
    driver_path = shutil.which("chromedriver")
    if binary is None:
        missing.append("a Chromium browser (" + " / ".join(BROWSER) + ")")
    if driver_path is None:
        missing.append("chromedriver")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        missing.append("selenium (pip install -e '.[test]')")
    if missing:
        message = f"missing {', '.join(missing)}: bash bin/setup.sh installs chromium and chromium-driver on Debian"
        if os.environ.get("CI") == "true":
            pytest.fail(f"the report's browser test must run under CI; {message}")
        pytest.skip(message)
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1600,1000",
                "--autoplay-policy=no-user-gesture-required",
                # a load from the network fails at once instead of waiting on a resolver; the log below catches it
                "--host-resolver-rules=MAP * ~NOTFOUND"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"performance": "ALL"})
    # the driver named explicitly: Selenium would otherwise try to download one
    driver = webdriver.Chrome(service=Service(executable_path=driver_path), options=options)
    yield driver
    driver.quit()


def wait_for(driver, script: str, *args, what: str):
    """Poll ``script`` (JavaScript returning a value) until it is truthy; its value."""
    from selenium.common.exceptions import TimeoutException
    from selenium.webdriver.support.ui import WebDriverWait

    try:
        return WebDriverWait(driver, WAIT_S, poll_frequency=0.2).until(lambda d: d.execute_script(script, *args))
    except TimeoutException:
        raise AssertionError(f"{what}: not there after {WAIT_S} s") from None


def network_loads(driver) -> list[str]:
    """The URLs the page asked for since the last call, that are not of the page itself (data:, file:, ...)."""
    urls = []
    for entry in driver.get_log("performance"):
        message = json.loads(entry["message"])["message"]
        if message["method"] == "Network.requestWillBeSent":
            urls.append(message["params"]["request"]["url"])
    return [url for url in urls if not url.startswith(LOCAL_SCHEMES)]


def open_report(driver, report: Path) -> None:
    driver.get(report.resolve().as_uri())
    wait_for(driver, "return typeof app !== 'undefined' && document.querySelector('#app').children.length > 0",
             what=f"{report}: the report's app")


def check_media(driver, where: str, root: str = "document") -> dict:
    """Every <img> and <video> under ``root`` (a JavaScript expression: an element, or the document of the current
    frame), loaded; their counts and the failures."""
    out = {"images": 0, "videos": 0, "failures": []}
    images = driver.execute_script(f"return {root}.querySelectorAll('img').length")
    for i in range(images):
        width = wait_for(driver, f"const im = {root}.querySelectorAll('img')[arguments[0]]; "
                         "return im.complete && (im.naturalWidth > 0 ? im.naturalWidth : 'broken')", i,
                         what=f"{where}: image {i}")
        out["images"] += 1
        if width == "broken":
            out["failures"].append(f"{where}: image {i} did not decode")
    videos = driver.execute_script(f"return {root}.querySelectorAll('video').length")
    for i in range(videos):
        state = wait_for(driver, f"const v = {root}.querySelectorAll('video')[arguments[0]]; "
                         "return v.error ? {error: v.error.code} : (v.readyState >= 1 ? {duration: v.duration} : null)",
                         i, what=f"{where}: video {i}'s metadata")
        out["videos"] += 1
        if "error" in state or not state["duration"] > 0:
            out["failures"].append(f"{where}: video {i} does not play: {state}")
    return out


# the element the report shows an item in: an <img> or an <iframe> whose source is the item's data
SHOWN = ("return Array.from(document.querySelectorAll('#app img, #app iframe'))"
         ".find(el => el.getAttribute('src') === results[arguments[0]].data_uri)")


def walk(driver) -> dict:
    """Go through every category, subcategory and item as a reader would, opening each item that shows in the page
    (images and HTML pages; others download); what was seen and what failed."""
    seen = {"items": [], "images": 0, "videos": 0, "failures": []}
    categories = driver.execute_script("return categories")
    for category, subcategories in categories.items():
        driver.execute_script("app.showCategory(arguments[0])", category)  # the menu's folder
        for subcategory, paths in subcategories.items():
            if len(subcategories) > 1:
                driver.execute_script("app.setView({navbarMode: 'subcategory', category: arguments[0], "
                                      "subcategory: arguments[1]})", category, subcategory)
            wait_for(driver, "return document.querySelectorAll('#app tbody tr').length",
                     what=f"{category} / {subcategory}: its list of items")
            for path in paths:
                seen["items"].append(path)
                where = f"{category} / {subcategory} / {path}"
                driver.execute_script("app.showResultInfo(arguments[0])", path)  # the item's ⓘ button
                # React renders after this script returns: wait for the item's page (its path in the breadcrumbs)
                wait_for(driver, "return document.querySelector('#app').innerText.includes(arguments[0])", path,
                         what=f"{where}: its page")
                caption = driver.execute_script("return results[arguments[0]].caption", path)
                if "system-message" in caption:
                    seen["failures"].append(f"{where}: its caption has a docutils error")
                mime = driver.execute_script("return results[arguments[0]].mime_type", path)
                if not (mime.startswith("image/") or mime == "text/html"):
                    continue
                driver.execute_script("document.querySelector('#app li a[type=button]').click()")  # the eye button
                shown = wait_for(driver, SHOWN, path, what=f"{where}: shown in the page")
                if mime == "text/html":
                    driver.switch_to.frame(shown)
                    try:
                        wait_for(driver, "return document.readyState === 'complete' && document.body && "
                                 "document.body.children.length > 0", what=f"{where}: the page in its frame")
                        found = check_media(driver, where)
                    finally:
                        driver.switch_to.default_content()
                else:
                    found = check_media(driver, where, root="document.querySelector('#app .p-3:has(> img)')")
                for key in ("images", "videos", "failures"):
                    seen[key] += found[key]
    return seen


def h264_clip(path: Path, frames: int = 20) -> Path:
    """A small H.264 MP4 (yuv420p, as the gallery writes them), made with imageio-ffmpeg's own ffmpeg."""
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(str(path), (64, 48), fps=10, codec="libx264", pix_fmt_out="yuv420p")
    writer.send(None)
    for i in range(frames):
        frame = np.zeros((48, 64, 3), np.uint8)
        frame[:, : 3 * i] = (40, 200, 120)
        writer.send(frame.tobytes())
    writer.close()
    return path


def test_a_gallery_video_plays_in_a_snakemake_report_that_loads_nothing_from_the_network(browser, tmp_path):
    """A one-rule workflow flags a folder of an MP4's page, the largest page video_page.write allows (under the
    longest file name) and a PNG, the way the gallery does: Debian's Chromium plays the H.264 video inside the
    single-file report, and the largest page still loads in the report's frame."""
    media = tmp_path / "src"
    media.mkdir()
    clip = h264_clip(tmp_path / "clip.mp4")
    assert video_page.write(clip, media / "episode.html", "row, class, seed", ("a line under it",)) > 0
    padding = video_page.PAGE_LIMIT - len(video_page.page(clip.read_bytes(), "largest", ("",)).encode())
    # a file name of 233 bytes: near the 255 a name may have, less the ".tmp-<pid>-" of atomic_path's temporary one
    longest = media / ("largest_" + "x" * 220 + ".html")
    # exact: the page's size is its bytes, counted
    assert video_page.write(clip, longest, "largest", ("x" * padding,)) == video_page.PAGE_LIMIT
    with pytest.raises(ValueError, match="over the .* a single-file"):
        video_page.write(clip, tmp_path / "too_big.html", "largest", ("x" * (padding + 1),))
    Image.new("RGB", (32, 16), (200, 40, 40)).save(media / "sheet.png")
    (tmp_path / "caption.rst").write_text("An episode of the gallery.\n")
    (tmp_path / "Snakefile").write_text('''
rule media:
    input:
        "src",
    output:
        report(directory("media"), patterns=["{name}.html", "{name}.png"], caption="caption.rst",
               category="Gallery", labels={"item": "{name}"}),
    shell:
        "cp -r {input} {output}"
''')
    run = [sys.executable, "-m", "snakemake", "-s", str(tmp_path / "Snakefile"), "--directory", str(tmp_path)]
    for args in (["--cores", "1"], ["--report", "report.html"]):
        proc = subprocess.run([*run, *args], cwd=tmp_path, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr[-3000:]
    open_report(browser, tmp_path / "report.html")
    seen = walk(browser)
    assert not seen["failures"], seen["failures"]
    assert (len(seen["items"]), seen["videos"], seen["images"]) == (3, 2, 1)
    assert network_loads(browser) == []


@pytest.fixture(scope="module")
def tiny_report(tiny_run):
    """The tiny run's report, of the targets the run built (the gallery's included)."""
    snakemake(tiny_run, "--configfile", "tiny.yaml", "--report", "report_browser.html", *TINY_TARGETS)
    return tiny_run / "report_browser.html"


def test_the_tiny_runs_report_opens_on_the_findings_and_every_item_opens(browser, tiny_run, tiny_report):
    open_report(browser, tiny_report)
    landing = wait_for(browser, "return document.querySelector('#app .prose') && "
                       "document.querySelector('#app .prose').innerText", what="the landing page's text")
    findings = pl.read_csv(tiny_run / "results" / "tables" / "findings_main.csv")
    for claim in findings["Claim"]:
        assert claim in landing, f"the landing page lacks finding claim {claim!r}"
    assert "Findings of the study, judged on this build" in landing
    assert "Table 5.1: spatial grounding" in landing and "Pure Visual" in landing
    assert "Profile cpu-default" in landing  # the line under each table
    assert "config profile cpu-default" in landing and "at commit" in landing
    assert "system-message" not in browser.execute_script("return workflow_desc")  # no docutils error on it
    seen = walk(browser)
    assert not seen["failures"], seen["failures"]
    # every report flag of the tiny run's rules
    assert {"results/tables/table5_1.csv", "results/tables/table5_2.csv", "results/tables/table5_6.csv",
            "results/tables/findings_main.csv", "results/tables/levers.csv", "results/figures/fig5_1.png",
            "results/figures/fig5_2.png", "results/figures/fig5_3.png"} <= set(seen["items"])
    assert seen["images"] >= 3
    # every MP4 the gallery wrote plays in the report, inside its page
    videos = list((tiny_run / "results").glob("gallery/**/*.mp4"))
    assert videos and seen["videos"] >= len(videos)
    assert network_loads(browser) == []
    screenshot = os.environ.get("OCPIPE_REPORT_SCREENSHOT")
    if screenshot:
        save_screenshot(browser, tiny_report, screenshot)


def test_a_built_report_opens_on_the_findings_and_every_item_opens(browser):
    """A report a run built, named by OCPIPE_REPORT (its run's results/ beside it), checked as the tiny run's is:
    `snakemake --report report.html spatial_grounding` after `make main` and `snakemake --cores 2 gallery`, then
    OCPIPE_REPORT=report.html pytest tests/test_report.py -k built_report (docs/development.md)."""
    given = os.environ.get("OCPIPE_REPORT")
    if not given:
        pytest.skip("no built report named: OCPIPE_REPORT=path/to/report.html checks one")
    report = Path(given).resolve()
    open_report(browser, report)
    landing = wait_for(browser, "return document.querySelector('#app .prose') && "
                       "document.querySelector('#app .prose').innerText", what="the landing page's text")
    assert "Findings of the study, judged on this build" in landing and "Table 5.1: spatial grounding" in landing
    seen = walk(browser)
    assert not seen["failures"], seen["failures"]
    videos = list((report.parent / "results").glob("gallery/**/*.mp4"))
    assert seen["videos"] >= len(videos), f"{len(videos)} gallery videos, {seen['videos']} played in the report"
    assert network_loads(browser) == []
    print(f"{report}: {len(seen['items'])} items, {seen['images']} images, {seen['videos']} videos "
          f"({len(videos)} gallery MP4 files)")
    screenshot = os.environ.get("OCPIPE_REPORT_SCREENSHOT")
    if screenshot:
        save_screenshot(browser, report, screenshot)


def save_screenshot(driver, report: Path, out) -> None:
    """The gallery's list beside its first video, paused half way (the landing page while there is no gallery)."""
    open_report(driver, report)
    gallery = driver.execute_script("return categories['Gallery'] || null")
    if gallery:
        subcategory, paths = next((sub, paths) for sub, paths in sorted(gallery.items())
                                  if any(p.endswith(".html") for p in paths))
        path = next(p for p in paths if p.endswith(".html"))
        # the list, and the video as its eye button shows it (one setView: React merges a second into the same state)
        driver.execute_script("app.setView({navbarMode: 'subcategory', category: 'Gallery', subcategory: arguments[0], "
                              "content: 'html', contentPath: results[arguments[1]].data_uri, "
                              "resultPath: arguments[1]})", subcategory, path)
        driver.switch_to.frame(wait_for(driver, SHOWN, path, what=f"{path}: shown in the page"))
        try:
            check_media(driver, path)
            driver.execute_script("const v = document.querySelector('video'); v.pause(); v.currentTime = v.duration/2")
            wait_for(driver, "const v = document.querySelector('video'); return !v.seeking && v.readyState >= 2",
                     what=f"{path}: its middle frame")
        finally:
            driver.switch_to.default_content()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    driver.save_screenshot(str(out))
