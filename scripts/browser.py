"""Headless Chromium for the kit's browser checks (`scripts/check_*.py`): selenium driving
the system's chromium and chromedriver.

Neither is part of `make test` or environment.txt: install them once with
    apt-get install chromium chromium-driver      (Debian; as root)
    .venv/bin/pip install selenium
"""
from __future__ import annotations

import os
import shutil
import socket
import sys

NEEDS = ("needs selenium (.venv/bin/pip install selenium) and Chromium with its driver "
         "(apt-get install chromium chromium-driver)")


def chrome():
    """A headless Chromium (1400x1000) that keeps the console's messages for `console_errors`.
    Exits 2 with one line saying what to install when selenium, chromium or chromedriver is missing."""
    binary = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    driver = shutil.which("chromedriver")
    try:
        from selenium import webdriver
    except ImportError:
        webdriver = None
    if webdriver is None or binary is None or driver is None:
        missing = [n for n, ok in (("selenium", webdriver), ("chromium", binary), ("chromedriver", driver)) if not ok]
        print(f"{os.path.basename(sys.argv[0])}: {', '.join(missing)} not found; {NEEDS}")
        sys.exit(2)
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for arg in ("--headless=new", "--window-size=1400,1000", "--disable-dev-shm-usage", "--disable-gpu",
                "--no-first-run", "--disable-extensions"):
        options.add_argument(arg)
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        options.add_argument("--no-sandbox")           # Chromium refuses to run as root with its sandbox
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=driver))


def console_errors(driver) -> list[str]:
    """The console's errors since the last call (SEVERE entries of the browser log)."""
    return [entry["message"] for entry in driver.get_log("browser") if entry.get("level") == "SEVERE"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
