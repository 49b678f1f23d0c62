"""Check that the labs' tests can fail: grade every lab with otter, as an instructor would.

For each lab (after ``make labs``: ``_build/labs/{student,autograder}/<lab>/``) this grades with
``otter run`` (no Docker) and the lab's autograder zip:

(a) the solution notebook (the autograder's copy of the master, with solutions): must score 100 %;
(b) the notebook as handed out (``_build/labs/student/<lab>/``): must score 0 on every question, and
    the grader must not crash;
(c) planted mistakes: copies of the solution with one typical error each (:data:`MISTAKES`, applied to
    the solution's source, so that they stay in step with it): each must lose points on exactly the
    question it breaks and keep every other question's full score.

Prints a table (lab, variant, score per question, total), writes ``_build/labs/grading.json`` and exits
1 if any expectation fails. Run from the project folder (``make check-labs``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import nbformat

ROOT = Path(__file__).resolve().parent.parent
BUILD = ROOT / "_build" / "labs"
LABS = ("lab1_models", "lab2_landmarks", "lab3_fastslam")

#: (lab, question, what the mistake is, find, replace): each applied once to the solution's code cells.
MISTAKES = [
    ("lab1_models", "q1", "wrap to [-pi, pi) instead of (-pi, pi]",
     "out = a - 2.0 * np.pi * np.ceil((a - np.pi) / (2.0 * np.pi))",
     "out = (a + np.pi) % (2.0 * np.pi) - np.pi"),
    ("lab1_models", "q2", "motion noise of v added to the turn",
     "dtheta = u[1] * dt + sigma_omega * np.sqrt(dt)",
     "dtheta = u[1] * dt + sigma_v * np.sqrt(dt)"),
    ("lab1_models", "q3", "bearing not wrapped",
     "wrap(np.arctan2(dy, dx) - x[2])",
     "np.arctan2(dy, dx) - x[2]"),
    ("lab1_models", "q4", "sign error in the bearing row of H",
     "[-dy / q, dx / q]]",
     "[dy / q, -dx / q]]"),
    ("lab1_models", "q5", "H_x without the -1 of the heading",
     "[dy / q, -dx / q, -1.0]]",
     "[dy / q, -dx / q, 0.0]]"),
    ("lab2_landmarks", "q1", "covariance updated with (I + KH)",
     "Sigma_new = (np.eye(2) - K @ H) @ Sigma",
     "Sigma_new = (np.eye(2) + K @ H) @ Sigma"),
    ("lab2_landmarks", "q1", "innovation's bearing not wrapped",
     "nu = np.array([z[0] - z_hat[0], wrap(z[1] - z_hat[1])])",
     "nu = np.array([z[0] - z_hat[0], z[1] - z_hat[1]])"),
    ("lab2_landmarks", "q2", "log-likelihood without the 2 pi",
     "np.log(np.linalg.det(2.0 * np.pi * Q))",
     "np.log(np.linalg.det(Q))"),
    ("lab2_landmarks", "q3", "weights exponentiated without the log-sum-exp shift",
     "w = np.exp(logw - np.max(logw))",
     "w = np.exp(logw)"),
    ("lab2_landmarks", "q4", "roulette ignores the weights",
     "idx = np.searchsorted(cdf, u, side=\"right\")",
     "idx = np.sort(rng.integers(0, M, size=M))"),
    ("lab2_landmarks", "q5", "systematic pointers off by one",
     "positions = (np.arange(M) + rng.random()) / M",
     "positions = (np.arange(1, M + 1) + rng.random()) / M"),
    ("lab3_fastslam", "q1", "heading taken at the end of the step",
     "theta = poses[:, 2]\n",
     "theta = poses[:, 2] + dtheta\n"),
    ("lab3_fastslam", "q2", "landmark initialised without the heading",
     "c, s = np.cos(phi + theta), np.sin(phi + theta)",
     "c, s = np.cos(phi), np.sin(phi)"),
    ("lab3_fastslam", "q3", "weights not normalised",
     "w = w / w.sum()",
     "w = w"),
    ("lab3_fastslam", "q4", "combined map from all particles, seen or not",
     "wn = np.divide(ws, tot, out=np.zeros_like(ws), where=observed)",
     "wn = np.repeat(w[:, None], ws.shape[1], axis=1)"),
    ("lab3_fastslam", "q5", "resampling copies the poses but not the maps",
     "poses, mu, Sigma, seen = poses[idx], mu[idx], Sigma[idx], seen[idx]",
     "poses = poses[idx]"),
]


def autograder_zip(lab: str) -> Path:
    zips = sorted((BUILD / "autograder" / lab).glob("*.zip"))
    if len(zips) != 1:
        raise SystemExit(f"expected one autograder zip in {BUILD / 'autograder' / lab}, found {len(zips)}: run `make labs`")
    return zips[0]


def plant(solution: Path, find: str, replace: str, out: Path) -> None:
    """A copy of the solution notebook with ``find`` replaced by ``replace`` (which must occur exactly once)."""
    nb = nbformat.read(solution, as_version=4)
    hits = [c for c in nb.cells if c.cell_type == "code" and find in c.source]
    count = sum(c.source.count(find) for c in hits)
    if count != 1:
        raise SystemExit(f"planted mistake: {find!r} occurs {count} times in {solution} (must be once)")
    hits[0].source = hits[0].source.replace(find, replace)
    nbformat.write(nb, out)


def grade(lab: str, variant: str, notebook: Path, workdir: Path) -> dict:
    """``otter run`` on one notebook: scores per question, or the error if the grader crashed."""
    out = workdir / "results"
    out.mkdir(parents=True, exist_ok=True)
    start = time.time()
    proc = subprocess.run(
        [str(Path(sys.executable).parent / "otter"), "run", "--no-logo", "-a", str(autograder_zip(lab)),
         "-o", str(out), str(notebook)],
        capture_output=True, text=True, cwd=workdir,
    )
    seconds = round(time.time() - start, 1)
    results = out / "results.json"
    if proc.returncode != 0 or not results.exists():
        return {"lab": lab, "variant": variant, "crashed": True, "seconds": seconds,
                "error": (proc.stdout + proc.stderr)[-3000:]}
    tests = json.loads(results.read_text())["tests"]
    scores = {t["name"]: [t["score"], t["max_score"]] for t in tests if t.get("max_score") is not None}
    return {"lab": lab, "variant": variant, "crashed": False, "seconds": seconds, "scores": scores}


def expectation(row: dict, breaks: str | None) -> list[str]:
    """What is wrong with ``row`` (empty: as expected). ``breaks``: None for the solution, "*" for the
    handed-out notebook, else the question the planted mistake breaks."""
    if row["crashed"]:
        return ["the grader crashed"]
    problems = []
    for q, (score, top) in row["scores"].items():
        if breaks is None and score != top:
            problems.append(f"{q}: {score}/{top}, the solution must score full marks")
        elif breaks == "*" and score != 0:
            problems.append(f"{q}: {score}/{top}, the handed-out notebook must score 0")
        elif breaks not in (None, "*") and q == breaks and not score < top:
            problems.append(f"{q}: {score}/{top}, the planted mistake must lose points here")
        elif breaks not in (None, "*") and q != breaks and score != top:
            problems.append(f"{q}: {score}/{top}, the planted mistake must not cost points here")
    if breaks not in (None, "*") and breaks not in row["scores"]:
        problems.append(f"no question {breaks} in the results")
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--labs", nargs="*", default=list(LABS), help="labs to check (default: all)")
    parser.add_argument("--jobs", type=int, default=2, help="notebooks graded at once (default 2)")
    parser.add_argument("--json", default=str(BUILD / "grading.json"))
    args = parser.parse_args(argv)

    work = Path(tempfile.mkdtemp(prefix="check-labs-"))
    jobs = []  # (lab, variant, notebook, breaks)
    try:
        for lab in args.labs:
            solution = BUILD / "autograder" / lab / f"{lab}.ipynb"
            student = BUILD / "student" / lab / f"{lab}.ipynb"
            for path in (solution, student):
                if not path.exists():
                    raise SystemExit(f"{path} is missing: run `make labs` first")
            jobs.append((lab, "solution", solution, None, ""))
            jobs.append((lab, "handed-out", student, "*", ""))
            for i, (mlab, question, what, find, replace) in enumerate(m for m in MISTAKES if m[0] == lab):
                planted = work / f"{lab}-mistake{i + 1}" / f"{lab}.ipynb"
                planted.parent.mkdir(parents=True)
                plant(solution, find, replace, planted)
                jobs.append((lab, f"mistake {i + 1} ({question})", planted, question, what))

        def run(job):
            lab, variant, notebook, breaks, what = job
            workdir = work / f"grade-{lab}-{variant.split()[0]}-{abs(hash(variant))}"
            row = grade(lab, variant, notebook, workdir)
            row["mistake"] = what
            row["expect"] = {None: "100 %", "*": "0 on every question"}.get(breaks, f"loses points on {breaks} only")
            row["problems"] = expectation(row, breaks)
            return row

        start = time.time()
        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            rows = list(pool.map(run, jobs))
        total_seconds = round(time.time() - start, 1)
    finally:
        shutil.rmtree(work, ignore_errors=True)

    # the table
    failed = False
    for lab in args.labs:
        lab_rows = [r for r in rows if r["lab"] == lab]
        questions = sorted({q for r in lab_rows if not r["crashed"] for q in r["scores"]})
        head = f"{'variant':<22}" + "".join(f"{q:>7}" for q in questions) + f"{'total':>13}  {'s':>5}  verdict"
        print(f"\n== {lab}\n{head}\n{'-' * len(head)}")
        for r in lab_rows:
            if r["crashed"]:
                cells, total = "".join(f"{'-':>7}" for _ in questions), "crashed"
            else:
                cells = "".join(f"{r['scores'][q][0]:>7.4g}" if q in r["scores"] else f"{'-':>7}" for q in questions)
                got = sum(s for s, _ in r["scores"].values())
                top = sum(t for _, t in r["scores"].values())
                total = f"{got:.4g}/{top:g}"
            verdict = "ok" if not r["problems"] else "FAIL: " + "; ".join(r["problems"])
            failed |= bool(r["problems"])
            print(f"{r['variant']:<22}{cells}{total:>13}  {r['seconds']:>5}  {verdict}"
                  + (f"  [{r['mistake']}]" if r["mistake"] else ""))
            if r["crashed"]:
                print(r["error"])
    print(f"\n{len(rows)} notebooks graded in {total_seconds} s ({args.jobs} at a time): "
          + ("every expectation met" if not failed else "SOME EXPECTATIONS FAILED"))

    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"seconds": total_seconds, "ok": not failed, "rows": rows}, indent=1))
    print(f"written: {args.json}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
