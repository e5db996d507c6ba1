"""Speed of the exported FMU (FMI 2.0, step-50g's model: n = 3, full fidelity, 50 g).

* **C, Co-Simulation**: ``fmi2DoStep`` of 1 ms (the adaptive Radau IIA inside, its
  default rtol 1e-8) from a C driver that loads the FMU's binary with ``dlopen``: a
  pressure step 0 -> 0.1 MPa at t = 0 from
  the equilibrium, then 2 s of 1 ms steps (the stiff filling, the load oscillation and the
  rest). Per step: the median over the run, and the median of the run means over
  ``--repeats`` runs.
* **C, Model Exchange**: ``fmi2SetContinuousStates`` + ``fmi2GetDerivatives`` at the
  equilibrium, in a loop of 100 000 calls, median of the ``--repeats`` loop means.
* **fmpy**: the same 1 ms Co-Simulation steps from Python (``FMU2Slave.doStep`` and one
  ``getReal`` of the length per step), median of the run means; the overhead is the
  difference to the C figure, and a loop of ``getReal`` alone gives the cost of one fmpy
  call (its ctypes conversions and status check).

Usage::

    python benchmarks/fmu_speed.py --out out/bench/fmu_speed.json [--repeats 7]
    python benchmarks/fmu_speed.py --scenario path/to/scene.toml   # another model, e.g. a level
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import tempfile
import time
import zipfile
from pathlib import Path

from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from sarcomere.fmu.export import fmi_headers
from sarcomere.scenarios.cli import main as cli

DRIVER = r"""
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}
static void logger(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c,
                   fmi2String m, ...) {
    (void)e; (void)s; (void)c;
    fprintf(stderr, "%s: %s\n", n, m);
}
#define LOAD(name) name##TYPE* name = (name##TYPE*)dlsym(lib, #name)

int main(int argc, char** argv) {
    /* argv: binary guid steps vr_p_cmd nx calls */
    void* lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 1; }
    LOAD(fmi2Instantiate); LOAD(fmi2SetupExperiment); LOAD(fmi2EnterInitializationMode);
    LOAD(fmi2ExitInitializationMode); LOAD(fmi2SetReal); LOAD(fmi2DoStep);
    LOAD(fmi2FreeInstance); LOAD(fmi2SetContinuousStates); LOAD(fmi2GetDerivatives);
    LOAD(fmi2GetContinuousStates); LOAD(fmi2EnterContinuousTimeMode);
    fmi2CallbackFunctions cb = {logger, NULL, NULL, NULL, NULL};
    long steps = atol(argv[3]), calls = atol(argv[6]);
    fmi2ValueReference vr = (fmi2ValueReference)atol(argv[4]);
    size_t nx = (size_t)atol(argv[5]);
    double p = 1e5, h = 1e-3, x[256], dx[256];
    fmi2Component cs = fmi2Instantiate("cs", fmi2CoSimulation, argv[2], "", &cb, 0, 0);
    fmi2SetupExperiment(cs, 0, 0, 0, 0, 0);
    fmi2EnterInitializationMode(cs);
    fmi2ExitInitializationMode(cs);
    fmi2SetReal(cs, &vr, 1, &p);
    double* dt = malloc(steps * sizeof *dt), total = now();
    for (long k = 0; k < steps; k++) {
        double t0 = now();
        if (fmi2DoStep(cs, k * h, h, fmi2True) != fmi2OK) return 2;
        dt[k] = now() - t0;
    }
    total = now() - total;
    fmi2FreeInstance(cs);
    fmi2Component me = fmi2Instantiate("me", fmi2ModelExchange, argv[2], "", &cb, 0, 0);
    fmi2SetupExperiment(me, 0, 0, 0, 0, 0);
    fmi2EnterInitializationMode(me);
    fmi2ExitInitializationMode(me);
    fmi2EnterContinuousTimeMode(me);
    fmi2GetContinuousStates(me, x, nx);
    double me_total = now();
    for (long k = 0; k < calls; k++) {
        x[0] += 1e-30 * (k & 1); /* a new state each call */
        fmi2SetContinuousStates(me, x, nx);
        if (fmi2GetDerivatives(me, dx, nx) != fmi2OK) return 3;
    }
    me_total = now() - me_total;
    fmi2FreeInstance(me);
    printf("%.9e %.9e\n", total / steps, me_total / calls);
    for (long k = 0; k < steps; k++) printf("%.9e\n", dt[k]);
    return 0;
}
"""


def instructions(driver: Path, binary: Path, guid: str, vr: int, nx: int, steps: int) -> dict:
    """Instructions (callgrind, inclusive) per 1 ms ``fmi2DoStep`` and per call of the
    integrator inside it (``sm_radau``), over the C driver's ``steps`` doSteps: a
    ratio that machine load does not move."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cg.out"
        cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", str(driver)]
        cmd += [str(binary), guid, str(steps), str(vr), str(nx), "1"]
        subprocess.run(cmd, capture_output=True, check=True)
        text = subprocess.run(
            ["callgrind_annotate", "--inclusive=yes", "--threshold=100", str(out)],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    found = {}
    for line in text.splitlines():
        for name in ("fmi2DoStep", "sm_radau", "sm_rhs", "sm_check_domain"):
            if line.rstrip().split(" [")[0].endswith(f":{name}") and name not in found:
                found[name] = int(line.split()[0].replace(",", "")) / steps
    return {
        "instructions_per_dostep": found["fmi2DoStep"],
        "instructions_per_integrator_call": found["sm_radau"],
        "dostep_over_integrator": found["fmi2DoStep"] / found["sm_radau"],
    }


def run(
    repeats: int, out: Path | None, scenario: str = "step-50g", callgrind: bool = False
) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="fmu-bench-"))
    fmu = tmp / "step-50g.fmu"
    tic = time.perf_counter()
    assert cli(["export-fmu", scenario, "--out", str(fmu)]) == 0
    export_s = time.perf_counter() - tic
    md = read_model_description(fmu)
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(tmp / "fmu")
    binary = tmp / "fmu" / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    vr = {v.name: v.valueReference for v in md.modelVariables}
    nx = len(md.derivatives)
    (tmp / "driver.c").write_text(DRIVER)
    subprocess.run(
        ["gcc", "-O2", "-I", str(fmi_headers()), str(tmp / "driver.c"), "-o", str(tmp / "driver")]
        + ["-ldl"],
        check=True,
    )
    steps, calls = 2000, 100_000
    cs_means, me_means, per_step = [], [], []
    for _ in range(repeats):
        done = subprocess.run(
            [str(tmp / "driver"), str(binary), md.guid, str(steps), str(vr["regulator.p_cmd"])]
            + [str(nx), str(calls)],
            capture_output=True,
            text=True,
            check=True,
        )
        lines = done.stdout.split()
        cs_means.append(float(lines[0]))
        me_means.append(float(lines[1]))
        per_step.extend(float(v) for v in lines[2:])
    per_step.sort()
    py_means, get_means = [], []
    for _ in range(repeats):
        fmpy_fmu = FMU2Slave(
            guid=md.guid,
            unzipDirectory=str(tmp / "fmu"),
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="py",
        )
        fmpy_fmu.instantiate()
        fmpy_fmu.setupExperiment(startTime=0.0)
        fmpy_fmu.enterInitializationMode()
        fmpy_fmu.exitInitializationMode()
        fmpy_fmu.setReal([vr["regulator.p_cmd"]], [1e5])
        length = [vr["myofibril.length"]]
        tic = time.perf_counter()
        for k in range(steps):
            fmpy_fmu.doStep(k * 1e-3, 1e-3)
            fmpy_fmu.getReal(length)
        py_means.append((time.perf_counter() - tic) / steps)
        tic = time.perf_counter()
        for _ in range(steps):
            fmpy_fmu.getReal(length)
        get_means.append((time.perf_counter() - tic) / steps)
        fmpy_fmu.terminate()
        fmpy_fmu.freeInstance()
    if callgrind:
        counts = instructions(tmp / "driver", binary, md.guid, vr["regulator.p_cmd"], nx, steps)
    cs_us = statistics.median(cs_means) * 1e6
    py_us = statistics.median(py_means) * 1e6
    result = {
        "model": md.modelName,
        "states": nx,
        "export_s": export_s,
        "repeats": repeats,
        "cs_dostep_1ms_mean_us": cs_us,
        "cs_dostep_1ms_median_us": statistics.median(per_step) * 1e6,
        "cs_dostep_1ms_p99_us": per_step[int(0.99 * len(per_step))] * 1e6,
        "me_derivatives_us": statistics.median(me_means) * 1e6,
        "fmpy_dostep_getreal_us": py_us,
        "fmpy_overhead_us": py_us - cs_us,
        "fmpy_getreal_alone_us": statistics.median(get_means) * 1e6,
    }
    if callgrind:
        result.update(counts)
    shutil.rmtree(tmp)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=2))
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="JSON file for the results")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument(
        "--callgrind",
        action="store_true",
        help="also count instructions per doStep and per integrator call (valgrind)",
    )
    parser.add_argument(
        "--scenario", default="step-50g", help="scenario file or packaged name (its model)"
    )
    args = parser.parse_args()
    for key, value in run(args.repeats, args.out, args.scenario, args.callgrind).items():
        print(f"{key:28s} {value:.4g}" if isinstance(value, float) else f"{key:28s} {value}")


if __name__ == "__main__":
    main()
