"""The MLflow dashboard as a user sees it: ``mlflow server`` on loopback and headless Chromium driven by
Selenium (MLflow's UI is a React app: the runs appear only after its JavaScript has queried the server).

Also a script, to refresh the README's screenshot from any store::

    .venv/bin/python -m tests.dashboard.browser sqlite:////path/mlflow.db docs/img/mlflow_dashboard.png
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator, Sequence
from pathlib import Path
from urllib.parse import quote

CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",  # we run as root in containers
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1600,900",
)
INSTALL_HINT = "install it with ./dev setup (or: apt-get install -y chromium chromium-driver)"


class DashboardError(RuntimeError):
    """The server or the browser could not be started or did not show what was expected."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def mlflow_server(store_uri: str, log_path: Path, timeout_s: float = 120.0) -> Iterator[str]:
    """``mlflow server`` on a free loopback port for the block; its base URL. The server's output goes to
    ``log_path`` (quoted in the error when it does not come up)."""
    port = free_port()
    cmd = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", store_uri]
    cmd += ["--host", "127.0.0.1", "--port", str(port), "--workers", "1"]
    url = f"http://127.0.0.1:{port}"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            if proc.poll() is not None:
                raise DashboardError(f"mlflow server exited with {proc.returncode}:\n{log_path.read_text()[-2000:]}")
            with contextlib.suppress(OSError), urllib.request.urlopen(f"{url}/health", timeout=2) as r:
                if r.status == 200:
                    break
            if time.monotonic() > deadline:
                raise DashboardError(f"mlflow server not up after {timeout_s:.0f} s:\n{log_path.read_text()[-2000:]}")
            time.sleep(0.5)
        yield url
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)  # its own session: the server and its workers, nothing else
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


@contextlib.contextmanager
def chromium(user_data_dir: Path) -> Iterator[object]:
    """A Selenium driver of headless Chromium through chromedriver (both from Debian's packages)."""
    binary = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_bin = shutil.which("chromedriver")
    if binary is None or driver_bin is None:
        missing = "chromium" if binary is None else "chromedriver"
        raise DashboardError(f"{missing} not found on PATH: {INSTALL_HINT}")
    from selenium import webdriver
    from selenium.common.exceptions import WebDriverException
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = binary
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={user_data_dir}"):
        options.add_argument(flag)
    try:
        driver = webdriver.Chrome(service=Service(driver_bin), options=options)
    except WebDriverException as exc:
        raise DashboardError(f"cannot start {binary} through {driver_bin}: {exc.msg}") from exc
    try:
        yield driver
    finally:
        driver.quit()


def wait_for(predicate, timeout_s: float, what: str, interval_s: float = 0.25):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(Exception):
            value = predicate()
            if value:
                return value
        time.sleep(interval_s)
    raise DashboardError(f"timed out after {timeout_s:.0f} s waiting for {what}")


def runs_page_url(base: str, experiment_id: str, search_filter: str, order_by: str) -> str:
    """The experiment's runs table with a filter and a sort order in the URL (what the search box sets)."""
    q = f"searchFilter={quote(search_filter)}&orderByKey={quote(order_by)}&orderByAsc=false"
    return f"{base}/#/experiments/{experiment_id}/runs?{q}"


def _set_column(driver, name: str, visible: bool) -> bool:
    """Tick (or untick) the column ``name`` in the open Columns menu's tree; whether it is now as asked.

    ``tag:<name>`` is a tag: the Tags section comes last, after a params group of the same name (the
    ``reward`` tag after ``reward.terms...``).
    """
    from selenium.webdriver.common.by import By

    is_tag = name.startswith("tag:")
    name = name.removeprefix("tag:")
    tree = "//*[@data-testid='column-selector-tree']"
    nodes = driver.find_elements(
        By.XPATH, f"{tree}//*[contains(@class,'tree-treenode')][.//*[normalize-space(text())='{name}']]"
    )
    for node in nodes[-1:] if is_tag else nodes[:1]:
        box = node.find_element(By.XPATH, ".//*[contains(@class,'tree-checkbox')]")
        if ("checkbox-checked" in (box.get_attribute("class") or "")) != visible:
            box.click()
            return False  # look again after the re-render
        return True
    return False


def show_columns(driver, columns: Sequence[str], hide: Sequence[str] = ("Dataset", "Source", "Models")) -> None:
    """Tick ``columns`` (metric or tag names) in the runs table's "Columns" menu, as a user would; untick
    the attribute columns ``hide`` a comparison does not need (more room for the metrics)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    def search_box():  # the menu re-renders on every tick: find it (and open it) again each time
        boxes = [
            b for b in driver.find_elements(By.XPATH, "//input[@placeholder='Search columns']") if b.is_displayed()
        ]
        if boxes:
            return boxes[0]
        next(b for b in driver.find_elements(By.TAG_NAME, "button") if b.text.strip() == "Columns").click()
        return None

    for name, visible in [*((h, False) for h in hide), *((c, True) for c in columns)]:

        def done(n: str = name, v: bool = visible) -> bool:
            box = search_box()
            if box is None:
                return False
            query = n.removeprefix("tag:")
            if box.get_attribute("value") != query:
                box.send_keys(Keys.CONTROL, "a")
                box.send_keys(query)
            return _set_column(driver, n, v)

        wait_for(done, 20, f"column {name!r} in the Columns menu")
    with contextlib.suppress(Exception):
        search_box().send_keys(Keys.ESCAPE)


def close_assistant(driver) -> None:
    """Close MLflow 3's assistant side panel when it is open (only to give the table the screen)."""
    from selenium.webdriver.common.by import By

    for xpath in (
        "//*[normalize-space(text())='MLflow Assistant']/ancestor::*[.//button][1]//button[last()]",
        "//button[@aria-label='Close']",
    ):
        for b in driver.find_elements(By.XPATH, xpath):
            with contextlib.suppress(Exception):
                if b.is_displayed():
                    b.click()
                    return


def table_text(driver) -> str:
    from selenium.webdriver.common.by import By

    return driver.find_element(By.TAG_NAME, "body").text


def table_rows(driver, run_names: Sequence[str], n_columns: int) -> dict[str, list[float]]:
    """Run name -> the numbers of its row (duration excluded) in the order the columns were added.

    MLflow's table renders a pinned part (names) and a scrolling part (values) as separate rows in the same
    order, so the i-th name row and the i-th value row are one run.
    """
    import re

    from selenium.webdriver.common.by import By

    texts = [r.text for r in driver.find_elements(By.XPATH, "//*[@role='row']")]
    names = [next(n for n in run_names if n in t) for t in texts if any(n in t for n in run_names)]
    number = re.compile(r"^-?\d+(\.\d+)?(e-?\d+)?$")
    values = []
    for t in texts:
        cells = [c for c in t.split("\n") if c]
        if (
            len(cells) == n_columns + 1
            and cells[0].endswith(("s", "ms", "min"))
            and all(number.match(c) for c in cells[1:])
        ):
            values.append([float(c) for c in cells[1:]])
    return dict(zip(names, values))


def capture_runs_page(
    base: str,
    experiment_id: str,
    run_names: Sequence[str],
    columns: Sequence[str],
    screenshot: Path,
    user_data_dir: Path,
    search_filter: str = "metrics.eval_spl >= 0",
    order_by: str = "metrics.`eval_spl`",
) -> tuple[str, dict[str, list[float]]]:
    """Open the runs page, wait for ``run_names``, show ``columns``, save a screenshot; the page's text and
    each run's numbers in the table (see :func:`table_rows`)."""
    with chromium(user_data_dir) as driver:
        driver.get(runs_page_url(base, experiment_id, search_filter, order_by))
        wait_for(lambda: all(n[:12] in table_text(driver) for n in run_names), 60, f"runs {list(run_names)}")
        close_assistant(driver)
        show_columns(driver, columns)
        shown = [c.removeprefix("tag:") for c in columns]
        wait_for(lambda: all(c in table_text(driver) for c in shown), 20, f"columns {shown}")
        with contextlib.suppress(Exception):  # no hover decorations (a row's pin button) in the picture
            from selenium.webdriver.common.action_chains import ActionChains
            from selenium.webdriver.common.by import By

            ActionChains(driver).move_to_element(driver.find_element(By.TAG_NAME, "h2")).perform()
        time.sleep(0.5)  # let the table settle before the picture
        screenshot.parent.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(screenshot))
        return table_text(driver), table_rows(driver, run_names, len(columns))


def main(argv: Sequence[str]) -> None:
    """``python -m tests.dashboard.browser STORE_URI OUT.png [EXPERIMENT]``: a screenshot of the runs page."""
    from mlflow.tracking import MlflowClient

    store, out = argv[0], Path(argv[1])
    exp_name = argv[2] if len(argv) > 2 else "diana_lab"
    client = MlflowClient(store)
    exp = client.get_experiment_by_name(exp_name)
    if exp is None:
        raise SystemExit(f"no experiment {exp_name} in {store}")
    names = [r.info.run_name for r in client.search_runs([exp.experiment_id], "metrics.eval_spl >= 0")]
    columns = ["tag:reward", "tag:seed", "eval_success_rate", "eval_spl", "eval_collision_rate"]
    with tempfile.TemporaryDirectory() as tmp, mlflow_server(store, Path(tmp) / "server.log") as url:
        capture_runs_page(url, exp.experiment_id, names, columns, out, Path(tmp) / "chrome")
    print(out)


if __name__ == "__main__":
    main(sys.argv[1:])
