"""Kill the review server with SIGKILL while operators relabel, and count the labels lost.

Usage::

    .venv/bin/python benchmarks/durability.py [--drive DRIVE --run RUN] [--trials 100]
        [--clients 4] [--json]

Without ``--drive``, a 30 m drive is simulated (``data_samples/scenes/test_straight.yaml``) and
processed with the shipped classifier into a temporary folder first (about a minute).

Each trial starts ``guardrail serve`` (the real command, its 3D scene included) on the drive with
one label store kept across trials, waits until ``/api/info`` answers, and runs ``--clients``
threads that relabel as fast as the server answers: ``PUT /api/segments/{id}/label``, and every
fifth request ``POST /api/labels/batch`` of up to eight segments. Each thread owns the segments
whose id modulo ``--clients`` is its number, so the order of one segment's changes is the order
its thread sent them. After a random 0.3-2 s of relabelling the server is killed with SIGKILL.

A label is *acknowledged* when its request was answered 200. The next trial's server (and one
more after the last trial) must show, for every segment, the label of its last acknowledged
request, or the label of a request that was in flight when the server died (sent, never
answered: either outcome is right). Anything else is a lost label. Reported: trials,
acknowledged requests and segment labels, lost (the target: 0), the server's start-up time
(median), and the requests per second.

Nothing is written into the drive or the run (``--review-dir`` is a temporary folder).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
GUARDRAIL = Path(sys.executable).with_name("guardrail")
LABELS = ("guardrail", "other")
#: Seconds a server may take to start before the trial fails (it is waited on, not slept).
START_LIMIT_S = 120.0


@dataclass
class ClientLog:
    """What one client thread sent and was told: per segment, the acknowledged label and the
    labels of requests never answered."""

    acked: dict[int, str] = field(default_factory=dict)
    in_flight: dict[int, set[str]] = field(default_factory=dict)
    requests: int = 0
    labels: int = 0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def prepare(work: Path, log: Path) -> tuple[Path, Path]:
    """Simulate and process the small test drive; return (drive, run). Their output goes to
    ``log`` (stdout carries only the figures)."""
    drive, run = work / "drive", work / "run"
    commands = [
        ["simulate", "--scene", "test_straight", "--seed", "11", "--quiet", str(drive)],
        ["process", str(drive), "--out", str(run), "--quiet"],
    ]
    with log.open("ab") as sink:
        for command in commands:
            subprocess.run([str(GUARDRAIL), *command], check=True, stdout=sink, stderr=sink)
    return drive, run


def start_server(drive: Path, run: Path, review: Path, log: Path) -> tuple[subprocess.Popen, str]:
    """Start ``guardrail serve`` and wait until its API answers; return it and its URL."""
    port = free_port()
    scene_port = free_port()
    url = f"http://127.0.0.1:{port}"
    process = subprocess.Popen(
        [
            str(GUARDRAIL), "serve", str(drive), "--run", str(run), "--port", str(port),
            "--scene-port", str(scene_port), "--review-dir", str(review),
            "--operator", "durability",
        ],
        stdout=log.open("ab"),
        stderr=subprocess.STDOUT,
    )  # fmt: skip
    deadline = time.monotonic() + START_LIMIT_S
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the server exited with {process.returncode}; see {log}")
        try:
            if httpx.get(f"{url}/api/info", timeout=2.0).status_code == 200:
                return process, url
        except httpx.TransportError:
            pass
        time.sleep(0.05)  # polling the server's state, not waiting for a time
    process.kill()
    raise RuntimeError(f"the server did not answer within {START_LIMIT_S:.0f} s; see {log}")


def segment_labels(url: str) -> dict[int, str | None]:
    """Every segment's operator label (None: not reviewed), read from the server."""
    out: dict[int, str | None] = {}
    offset = 0
    while True:
        page = httpx.get(f"{url}/api/segments", params={"offset": offset, "limit": 1000}).json()
        for item in page["items"]:
            out[item["id"]] = item["label"] if item["reviewed"] else None
        offset += len(page["items"])
        if offset >= page["total"]:
            return out


def relabel(url: str, mine: list[int], log: ClientLog, stop: threading.Event, seed: int) -> None:
    """Relabel ``mine`` until the server dies or ``stop`` is set."""
    rng = random.Random(seed)
    with httpx.Client(base_url=url, timeout=30.0) as client:
        while not stop.is_set():
            label = rng.choice(LABELS)
            if log.requests % 5 == 4:
                ids = sorted(rng.sample(mine, min(len(mine), rng.randint(2, 8))))
                request = ("POST", "/api/labels/batch", {"segments": ids, "label": label})
            else:
                ids = [rng.choice(mine)]
                request = ("PUT", f"/api/segments/{ids[0]}/label", {"label": label})
            for s in ids:
                log.in_flight.setdefault(s, set()).add(label)
            try:
                answer = client.request(request[0], request[1], json=request[2])
            except httpx.TransportError:
                return  # the server died with this request in flight
            if answer.status_code != 200:
                raise RuntimeError(f"{request[:2]} answered {answer.status_code}: {answer.text}")
            log.requests += 1
            log.labels += len(ids)
            for s in ids:
                log.acked[s] = label
                log.in_flight[s].clear()


def check(
    state: dict[int, str | None], expected: dict[int, tuple[str | None, set[str]]]
) -> list[str]:
    """The segments whose label is neither the acknowledged one nor one in flight."""
    lost = []
    for s, (acked, in_flight) in expected.items():
        if state.get(s) != acked and state.get(s) not in in_flight:
            lost.append(
                f"segment {s}: {state.get(s)} (acknowledged {acked}, in flight {in_flight})"
            )
    return lost


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drive", type=Path)
    parser.add_argument("--run", type=Path)
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="durability-"))
    finished = False
    try:
        review, server_log = work / "review", work / "server.log"
        drive, run = (args.drive, args.run) if args.drive else prepare(work, server_log)
        rng = random.Random(args.seed)
        expected: dict[int, tuple[str | None, set[str]]] = {}
        lost: list[str] = []
        starts, rates = [], []
        requests = labels = 0
        for trial in range(args.trials + 1):
            t0 = time.perf_counter()
            process, url = start_server(drive, run, review, server_log)
            starts.append(time.perf_counter() - t0)
            state = segment_labels(url)
            lost += [f"trial {trial}: {line}" for line in check(state, expected)]
            # What the server shows now is the truth the next trial builds on.
            expected = {s: (label, set()) for s, label in state.items() if label is not None}
            if trial == args.trials:
                process.kill()
                process.wait()
                break
            segments = sorted(state)
            logs = [ClientLog() for _ in range(args.clients)]
            stop = threading.Event()
            threads = [
                threading.Thread(
                    target=relabel,
                    args=(url, segments[k :: args.clients], logs[k], stop, rng.randrange(2**32)),
                )
                for k in range(args.clients)
            ]
            began = time.perf_counter()
            for thread in threads:
                thread.start()
            time.sleep(rng.uniform(0.3, 2.0))  # the moment of the crash is what varies
            os.kill(process.pid, signal.SIGKILL)
            process.wait()
            stop.set()
            for thread in threads:
                thread.join()
            elapsed = time.perf_counter() - began
            for log in logs:
                requests += log.requests
                labels += log.labels
                for s, label in log.acked.items():
                    expected[s] = (label, set())
                for s, pending in log.in_flight.items():
                    if pending:
                        acked = expected.get(s, (None, set()))[0]
                        expected[s] = (acked, set(pending))
            rates.append(sum(log.requests for log in logs) / elapsed)
            print(
                f"trial {trial + 1}/{args.trials}: {sum(log.requests for log in logs)} requests "
                f"acknowledged, lost so far {len(lost)}",
                file=sys.stderr,
            )
        figures = {
            "trials": args.trials,
            "clients": args.clients,
            "acknowledged_requests": requests,
            "acknowledged_segment_labels": labels,
            "lost": len(lost),
            "lost_examples": lost[:10],
            "server_start_s_median": round(statistics.median(starts), 2),
            "requests_per_s_median": round(statistics.median(rates), 1),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}",
        }
        finished = True
    finally:
        if finished:
            shutil.rmtree(work, ignore_errors=True)
        else:  # the server's log and the label store tell what went wrong
            print(f"kept {work} for a look", file=sys.stderr)
    if args.json:
        print(json.dumps(figures, indent=1))
    else:
        print(
            f"{figures['trials']} SIGKILL trials, {figures['clients']} clients: "
            f"{requests:,} requests ({labels:,} segment labels) acknowledged, "
            f"{len(lost)} lost; the server starts in {figures['server_start_s_median']} s "
            f"(median), {figures['requests_per_s_median']} requests/s (median)"
        )
        for line in lost[:10]:
            print("  lost:", line)
    return 1 if lost else 0


if __name__ == "__main__":
    sys.exit(main())
