"""End to end in a real browser: server on 127.0.0.1, headless Chromium driven through the page.

Skips (with the reason) only where Chromium or its driver is not installed; ``make test`` installs
both from Debian's packages.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from PIL import Image
from retrieval_fakes import FakeEmbedder, HashTextEncoder, caption_of, make_clips_dir, make_run_dir

from retrieval.embedding import model_hash
from retrieval.scenesearch import SceneSearch
from retrieval.service import ServiceLimits, create_app, serving_in_thread

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not (Path(CHROMIUM).exists() and Path(CHROMEDRIVER).exists()),
                       reason="Chromium and chromedriver are not installed "
                              "(Debian packages chromium, chromium-driver)"),
]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    root = tmp_path_factory.mktemp("browser")
    clips = make_clips_dir(root / "clips", n_logs=4, clips_per_log=8)
    for i, row in enumerate(pq.read_table(clips / "clips.parquet").to_pylist()):
        path = clips / row["preview_path"]
        path.parent.mkdir(parents=True, exist_ok=True)
        frames = [Image.new("RGB", (64, 32), (30 + 5 * i, 60 + 40 * f, 90)) for f in range(3)]
        frames[0].save(path, save_all=True, append_images=frames[1:], duration=120, loop=0)
    run = make_run_dir(root / "run")
    search = SceneSearch.build(run, clips, root / "index", embedder=FakeEmbedder(model_hash(run)),
                               text_encoder=HashTextEncoder())
    with serving_in_thread(create_app(search), ServiceLimits()) as url:
        yield {"url": url + "/", "root": root}


@pytest.fixture(scope="module")
def browser(server: dict[str, Any]) -> Iterator[Any]:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    os.environ.setdefault("SE_OFFLINE", "true")  # never let Selenium look for drivers online
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", "--window-size=1400,1000",
                 f"--user-data-dir={server['root'] / 'chromium-profile'}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(30)
    try:
        yield driver
    finally:
        driver.quit()


def _wait(predicate: Any, timeout_s: float = 15.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError("condition not met within the time limit")


def _open_and_search(browser: Any, url: str, query: str, mode: str = "model") -> list[Any]:
    """Load the page, choose the search mode, type ``query``, search; the result cards."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    browser.get(url)
    _wait(lambda: len(browser.find_elements(By.CSS_SELECTOR, "#f-category option")) > 1)
    Select(browser.find_element(By.ID, "mode")).select_by_value(mode)
    box = browser.find_element(By.ID, "query")
    box.clear()
    box.send_keys(query)
    browser.find_element(By.ID, "search-button").click()
    return list(_wait(lambda: browser.find_elements(By.CSS_SELECTOR, "#results .card")))


def _previews_loaded(browser: Any) -> bool:
    """Whether every preview in the window has loaded (those further down load lazily, when scrolled to)."""
    return bool(browser.execute_script(
        "const shown = [...document.querySelectorAll('img.preview')].filter(i => i.getBoundingClientRect().top < "
        "innerHeight); return shown.length > 0 && shown.every(i => i.complete && i.naturalWidth > 0)"))


def _shot(browser: Any, server: dict[str, Any], name: str) -> None:
    shot_dir = Path(os.environ.get("SCENESEARCH_SCREENSHOT_DIR", server["root"]))
    shot_dir.mkdir(parents=True, exist_ok=True)
    assert browser.save_screenshot(str(shot_dir / name))


def test_query_previews_and_more_like_this(server: dict[str, Any], browser: Any) -> None:
    from selenium.webdriver.common.by import By

    query = caption_of(["host:constant", "host:stop"])
    cards = _open_and_search(browser, server["url"], query)
    assert len(cards) == 12
    assert cards[0].find_element(By.CSS_SELECTOR, ".caption").text.endswith(query)
    # Every preview image in view really loaded (decoded, non-zero size), not just an <img> tag.
    _wait(lambda: _previews_loaded(browser))

    first_id = cards[0].get_attribute("data-clip-id")
    cards[0].find_element(By.CSS_SELECTOR, ".more-like-this").click()
    _wait(lambda: "moments like" in browser.find_element(By.ID, "status").text)
    similar_ids = [c.get_attribute("data-clip-id") for c in browser.find_elements(By.CSS_SELECTOR, "#results .card")]
    assert similar_ids and first_id not in similar_ids

    browser.find_elements(By.CSS_SELECTOR, "#results .card .details")[0].click()
    timeline = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "#timeline div"))
    assert [t.text for t in timeline]  # the steps of the clip's tag sequence, in order
    browser.find_element(By.ID, "detail-close").click()

    shot_dir = Path(os.environ.get("SCENESEARCH_SCREENSHOT_DIR", server["root"]))
    shot_dir.mkdir(parents=True, exist_ok=True)
    browser.find_element(By.ID, "query").clear()
    browser.find_element(By.ID, "query").send_keys(query)
    browser.find_element(By.ID, "search-button").click()
    _wait(lambda: "results for" in browser.find_element(By.ID, "status").text)
    assert browser.save_screenshot(str(shot_dir / "web_page.png"))


def test_hybrid_mode_from_the_page(server: dict[str, Any], browser: Any) -> None:
    from selenium.webdriver.common.by import By

    query = caption_of(["left:approach", "left:cut_in"])
    cards = _open_and_search(browser, server["url"], query, mode="hybrid")
    assert cards[0].find_element(By.CSS_SELECTOR, ".caption").text.endswith(query)


def test_errors_are_shown_on_the_page(server: dict[str, Any], browser: Any) -> None:
    from selenium.webdriver.common.by import By

    browser.get(server["url"] + "?q=" + "x" * 600)  # longer than the server's limit: the page says so
    # The page says "Searching…" while the request is out: wait for the answer, not the first text.
    status = _wait(lambda: (text := browser.find_element(By.ID, "status").text) and "Searching" not in text and text)
    assert "413" in status


def test_landing_page_offers_examples_and_the_index_summary(server: dict[str, Any], browser: Any) -> None:
    from selenium.webdriver.common.by import By

    browser.get(server["url"])
    examples = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "#examples button"))
    assert "32" in browser.find_element(By.ID, "summary").text  # 4 logs × 8 clips
    text = examples[0].text
    examples[0].click()
    cards = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "#results .card"))
    assert cards and browser.find_element(By.ID, "query").get_attribute("value") == text
    assert "q=" in browser.current_url


def test_more_like_this_pins_the_query_and_says_so_in_the_box_and_address(server: dict[str, Any],
                                                                          browser: Any) -> None:
    from selenium.webdriver.common.by import By

    cards = _open_and_search(browser, server["url"], caption_of(["left:approach", "left:cut_in"]))
    first_id = cards[0].get_attribute("data-clip-id")
    cards[0].find_element(By.CSS_SELECTOR, ".more-like-this").click()
    pinned = _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "#pinned .card"))
    assert pinned[0].get_attribute("data-clip-id") == first_id
    assert browser.find_element(By.ID, "query").get_attribute("value") == "like: " + first_id
    assert "like=" in browser.current_url
    results = [c.get_attribute("data-clip-id") for c in browser.find_elements(By.CSS_SELECTOR, "#results .card")]
    assert results and first_id not in results
    _shot(browser, server, "web_page_similar.png")
    browser.back()  # the address holds the whole state: back returns to the search
    _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "#pinned[hidden]"))
    assert browser.find_element(By.ID, "query").get_attribute("value").startswith("a car in the left lane")


def test_a_filter_and_pages_live_in_the_address(server: dict[str, Any], browser: Any) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    _open_and_search(browser, server["url"], "keeps its distance ahead")
    Select(browser.find_element(By.ID, "k")).select_by_visible_text("6")
    Select(browser.find_element(By.ID, "f-category")).select_by_value("truck")
    _wait(lambda: "category%3Dtruck" in browser.current_url and "k=6" in browser.current_url)

    def categories() -> list[str]:  # read in one go: the cards are replaced while a search answers
        return [t.split(" · ")[0] for t in browser.execute_script(
            "return [...document.querySelectorAll('#results .card .meta')].map(m => m.textContent.trim())")]

    def shown() -> list[str]:
        return list(browser.execute_script(
            "return [...document.querySelectorAll('#results .card')].map(c => c.dataset.clipId)"))

    _wait(lambda: categories() and all(c == "truck" for c in categories()))
    first_page = shown()
    browser.find_element(By.ID, "next-page").click()
    _wait(lambda: "page=2" in browser.current_url and browser.find_element(By.ID, "page-info").text.startswith("7"))
    second_page = shown()
    assert second_page and not set(first_page) & set(second_page)
    ranks = [c.text for c in browser.find_elements(By.CSS_SELECTOR, "#results .card .rank")]
    assert ranks[0] == "#7"
    browser.refresh()  # the same view again from the address alone
    _wait(lambda: shown() == second_page)
    assert Select(browser.find_element(By.ID, "f-category")).first_selected_option.get_attribute("value") == "truck"
    _shot(browser, server, "web_page_filtered.png")


def test_embedding_map_opens_a_clip(server: dict[str, Any], browser: Any) -> None:
    from selenium.webdriver.common.by import By

    browser.get(server["url"] + "?map=1")
    _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "#map-legend span"))
    # A click on the first point, where the page draws it.
    clicked = browser.execute_script(
        "const c = document.getElementById('map-canvas'); c.scrollIntoView(); const b = c.getBoundingClientRect();"
        "const [x, y] = mapXY(MAP.points[0], c);"
        "c.dispatchEvent(new MouseEvent('click', {bubbles: true, clientX: b.left + x * b.width / c.width,"
        "                                         clientY: b.top + y * b.height / c.height}));"
        "return MAP.clip_ids[0];")
    _wait(lambda: browser.find_elements(By.CSS_SELECTOR, "#detail:not([hidden]) #timeline div"))
    assert clicked in browser.find_element(By.ID, "detail-body").text
