"""The built site in a real browser: headless Chromium (Debian's ``chromium`` and
``chromium-driver``; ``.ci/run`` installs them when missing; nothing is downloaded here)
opens the landing page, an API page, a gallery page and the search page, served from
127.0.0.1: no console error, every image drawn, every same-site link answered, the
search finds ``export_fmu``, and a screenshot of each page in the output folder
(``docs/_build/browser``, or ``SARCOMERE_DOCS_SHOTS``)."""

from __future__ import annotations

import functools
import os
import shutil
import sys
import threading
import time
import urllib.request
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import urljoin, urlsplit

import pytest
from selenium import webdriver  # the docs extra: a missing selenium fails, never skips
from selenium.webdriver.common.by import By

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1280,1000",
]
PAGES = {
    "landing": "index.html",
    "api": "api/generated/sarcomere.fmu.export_fmu.html",
    "gallery": "gallery/plot_09_fmu_fmpy.html",
    "search": "search.html?q=export_fmu",
}


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


class _Server(ThreadingHTTPServer):
    def handle_error(self, request, client_address):
        """A request the browser dropped (a page left early) is no failure of the site."""
        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


@pytest.fixture(scope="module")
def site(html):
    server = _Server(("127.0.0.1", 0), functools.partial(_Quiet, directory=html))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}/"
    server.shutdown()
    server.server_close()


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if not (CHROMIUM and DRIVER):
        pytest.fail("no chromium/chromedriver: apt-get install chromium chromium-driver")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(DRIVER))
    driver.set_page_load_timeout(30)
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def shots(html) -> Path:
    folder = Path(os.environ.get("SARCOMERE_DOCS_SHOTS", html.parent / "browser"))
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _errors(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def _open(driver, url: str) -> None:
    driver.get(url)
    end = time.monotonic() + 20
    while driver.execute_script("return document.readyState") != "complete":
        assert time.monotonic() < end, f"{url} did not finish loading"
        time.sleep(0.1)


@pytest.mark.parametrize("page", ["landing", "api", "gallery"])
def test_the_page_shows_without_errors(browser, site, shots, page):
    url = site + PAGES[page]
    _open(browser, url)
    browser.save_screenshot(str(shots / f"{page}.png"))
    errors = _errors(browser)
    assert not errors, errors
    broken = browser.execute_script(
        "return [...document.images].filter(i => !(i.complete && i.naturalWidth > 0))"
        ".map(i => i.src)"
    )
    assert not broken, f"images not drawn on {url}: {broken}"
    if page != "api":  # the landing page's figure, the example's plot
        assert browser.find_elements(By.CSS_SELECTOR, "img"), f"no image on {url}"
    hrefs = {
        urljoin(url, a.get_attribute("href")).split("#")[0]
        for a in browser.find_elements(By.CSS_SELECTOR, "a[href]")
    }
    same_site = sorted(h for h in hrefs if h.startswith(site))
    assert same_site
    for href in same_site:
        with urllib.request.urlopen(href, timeout=10) as answer:
            assert answer.status == 200, href
    if page == "landing":  # the four entry points are one click away
        for name in ("simulate", "export_fmu", "NonlinearMPC", "Study"):
            assert any(urlsplit(h).path.endswith(f".{name}.html") for h in same_site), name


def test_search_finds_the_page_of_export_fmu(browser, site, shots):
    _open(browser, site + PAGES["search"])
    end, found = time.monotonic() + 30, []
    while time.monotonic() < end and not found:
        time.sleep(0.25)
        found = [
            a.get_attribute("href")
            for a in browser.find_elements(By.CSS_SELECTOR, "#search-results a[href]")
            if "sarcomere.fmu.export_fmu.html" in a.get_attribute("href")
        ]
    browser.save_screenshot(str(shots / "search.png"))
    assert found, "the search for export_fmu did not list its API page"
    errors = _errors(browser)
    assert not errors, errors
