"""What an operator sees in Yamcs's web interface (issue 40 item 6), checked in a real browser: headless
Chromium (Debian's ``chromium``, driven through the DevTools protocol) on the parameter page of G and d of
both GRS while the ground sets them, and on the command history of tables verified from onboard reports.
Each page is waited for until it shows the data, saved as a PNG (``TAIJI2_SCREENSHOTS``: where to keep them,
e.g. docs/img; else the test's temporary directory) and its DOM asserted to show the values."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from chromium_cdp import Browser, chromium_path
from spacepackets.ecss.tc import PusTc

from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL
from taiji2_ground_pkg.mcs.yamcs_api import credentials, set_parameters
from taiji2_ground_pkg.mcs.yamcs_security import OBSERVER
from taiji2_runtime.packets.scheduling import FAILURE_LATE, Activity, encode_insert_activities, encode_report

from support import command_through_yamcs, require_yamcs, running_yamcs

require_yamcs()
if chromium_path() is None:
    pytest.skip("browser check skipped: Debian's chromium is not installed (apt-get install chromium)",
                allow_module_level=True)

#: the estimates an operator would see mid-run (values with few digits: the page shows them exactly); GRS1's
#: G_Pphi sigma above its requirement, so its alarm must show
ESTIMATES = {
    **{f"grs{g}_G_{axis}": v * (1 + 0.01 * g) for g in (1, 2)
       for axis, v in (("Pphi", 7.4047e-8), ("Ptheta", 7.3125e-8), ("Ppsi", 1.2968e-8))},
    **{f"grs{g}_G_{axis}_rel_sigma": s for g in (1, 2) for axis, s in (("Pphi", 0.0041 / g), ("Ptheta", 0.0012),
                                                                       ("Ppsi", 0.0025))},
    **{f"grs{g}_d_{axis}": v * g for g in (1, 2) for axis, v in (("x", 0.0015), ("y", -0.00082), ("z", 0.00031))},
    **{f"grs{g}_d_{axis}_sigma": s for g in (1, 2) for axis, s in (("x", 2.1e-5), ("y", 3.4e-5), ("z", 8.5e-5))},
}
#: pushes of the values while waiting for the page (the station pushes once a second): a guard against a page
#: that never shows them, not a measurement
MAX_PUSHES = 240
#: the table rows of a Yamcs list page: each row's cells' text
ROWS_JS = ("Array.from(document.querySelectorAll('tr')).map("
           "r => Array.from(r.querySelectorAll('td')).map(td => td.innerText.trim()))")


def _signed_in(page: Browser, base: str, credentials_file: Path) -> None:
    """Sign in on Yamcs's login form (authentication is on) with the credentials of ``credentials_file``."""
    user, password = credentials({"YAMCS_CREDENTIALS_FILE": str(credentials_file)})
    page.navigate(f"{base}/")
    for _ in range(MAX_PUSHES):
        if page.evaluate("!!document.querySelector('input[name=password]')"):
            break
        page.pause(0.25)
    page.evaluate(f"document.querySelector('input[name=username]').value = {json.dumps(user)};"
                  f"document.querySelector('input[name=password]').value = {json.dumps(password)};"
                  "document.querySelector('input[name=login]').click()")
    for _ in range(MAX_PUSHES):
        text = page.text()
        if text and "Sign in" not in text and "Loading" not in text:
            return
        page.pause(0.25)
    raise AssertionError(f"not signed in: {page.text()[:300]}")


def _shots(tmp_path: Path) -> Path:
    folder = Path(os.environ.get("TAIJI2_SCREENSHOTS") or tmp_path)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _shown_values(page: Browser) -> dict[str, str]:
    """``{parameter: value cell}`` of the parameter list on the page (name cells read ``/taiji2/NAME``)."""
    out = {}
    for cells in page.evaluate(ROWS_JS) or []:
        if len(cells) >= 4 and "/taiji2/" in cells[0]:
            out[cells[0].rsplit("/", 1)[-1]] = cells[3]
    return out


def _over_requirement(name: str, value: float) -> bool:
    if name.endswith("_rel_sigma"):
        return value > SCALE_FACTOR_REQUIREMENT_REL
    return name.endswith("_sigma") and value > COM_OFFSET_REQUIREMENT_M


@pytest.fixture(scope="module")
def yamcs(tmp_path_factory):
    with running_yamcs(tmp_path_factory.mktemp("yamcs")) as server:
        yield server


def test_the_parameter_page_shows_g_and_d_of_both_grs_with_their_alarms(yamcs, tmp_path):
    base = f"http://127.0.0.1:{yamcs.http_port}"
    with Browser() as page:
        _signed_in(page, base, yamcs.credentials_file(OBSERVER))  # reading needs no more than an observer
        for g in (1, 2):
            wanted = {k: v for k, v in ESTIMATES.items() if k.startswith(f"grs{g}_")}
            page.navigate(f"{base}/telemetry/parameters?c=taiji2__realtime&filter=grs{g}_")
            for _ in range(MAX_PUSHES):
                set_parameters(yamcs.url, wanted)
                shown = _shown_values(page)
                if all(shown.get(k, "-") != "-" for k in wanted):
                    break
                page.pause(0.5)  # the ground pushes about once a second
            shot = page.screenshot(_shots(tmp_path) / f"yamcs_parameters_grs{g}.png")
            assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 10_000
            for name, value in wanted.items():
                cell = shown[name]
                assert float(cell.split()[0]) == pytest.approx(value, rel=1e-12), (name, cell)
                # Yamcs marks a value beyond its alarm range with an arrow (its tooltip: "High")
                assert ("↑" in cell) == _over_requirement(name, value), (name, cell)
            assert sum("↑" in shown[k] for k in wanted) == (g == 1)


def test_the_command_history_shows_each_table_verified_and_the_late_one_failed_with_its_reason(yamcs, tmp_path):
    tables = [encode_insert_activities(k, [Activity(10**12 * (k + 1), (1e-6, -2e-6, 3e-6 * k))], k)
              for k in range(2)]

    def reports(sent):  # the first accepted and executed, the second accepted and refused as late
        tcs = [PusTc.unpack(p) for p in sent]
        return [encode_report(1, tcs[0], 10**9, 0), encode_report(7, tcs[0], 10**9 + 1, 1),
                encode_report(1, tcs[1], 10**9 + 2, 2), encode_report(8, tcs[1], 10**9 + 3, 3, FAILURE_LATE, 3)]

    _, history = command_through_yamcs(yamcs, tables, reports, {"Acceptance": 2, "Execution": 2})
    assert [h["Execution"] for h in history] == ["OK", "NOK"], history
    base = f"http://127.0.0.1:{yamcs.http_port}"
    with Browser() as page:
        _signed_in(page, base, yamcs.credentials_file(OBSERVER))
        page.navigate(f"{base}/commanding/history?c=taiji2__realtime")
        for _ in range(MAX_PUSHES):
            rows = [cells for cells in page.evaluate(ROWS_JS) or [] if any("insert_activities" in c for c in cells)]
            if len(rows) >= 2:
                break
            page.pause(0.5)
        page.screenshot(_shots(tmp_path) / "yamcs_command_history.png")
        completion = sorted(cells[-2] for cells in rows)
        assert completion == ["FAILURE", "SUCCESS"], rows
        # the failed table's own page names the onboard reason
        failed = history[1]["id"]
        page.navigate(f"{base}/commanding/history/{failed}?c=taiji2__realtime")
        for _ in range(MAX_PUSHES):
            if "refused onboard" in page.text():
                break
            page.pause(0.5)
        page.evaluate("[...document.querySelectorAll('*')].filter(e => !e.children.length && "
                      "e.textContent.includes('refused onboard'))[0]?.scrollIntoView({block: 'center'})")
        page.screenshot(_shots(tmp_path) / "yamcs_command_failed.png")
        assert "refused onboard: LATE, 3 activities not scheduled" in page.text()
