"""Closed-loop throughput benchmark (never a unit test).

    python experiments/perf/run.py            # readable table
    python experiments/perf/run.py --json     # one JSON object per line and configuration

Configurations (``--configs``, default both):

* ``state_only`` = dynamics + replay + infractions + criteria + vector
  observations with the ``log_replay`` policy, at batch sizes B (default 1,
  64, 800 scenarios of the suite). ``log_replay`` reads only the privileged
  log controls, so XLA leaves the rest of the observation out;
* ``state_obs`` (not in the default) = ``state_only`` with a policy that also
  reads every vector-observation leaf: the closed loop including the
  observation;
* ``state_idm`` (not in the default) = ``state_only`` with the reactive IDM
  agents (``SimConfig(agents="idm")``): their leaders along their paths;
* ``sweep_bev_lidar`` = the whole suite (800 episodes x the episode length,
  ``Simulator.episode_steps``: 200 steps of 0.1 s on twin15) with
  the 128 x 128 BEV and the 64 x 360 LiDAR on and a small MLP policy reading
  both (issue budget: <= 60 s after compilation); reports ``wall_s`` and
  ``compile_s`` (ahead-of-time lower + compile of init and advance), the
  process ``cpu_s`` of the timed loop and the 1-minute load average before
  and after it (on a shared machine the wall varies by ~40 %).
 ``--against-waymax ../wmx/venv/bin/python`` (the venv that
  ``../shared/anchors/waymax/setup.sh`` makes) runs the state configurations
  and Waymax's bare step side by side, ``--rounds`` times interleaved, each
  in a fresh process, and prints the best-of ratios (the issue's report).
 For each it reports scenario-steps/s,
agent-steps/s (valid replayed agents, the ego included, summed over the
simulated steps), compile time cold and from JAX's persistent compilation
cache (each measured in a fresh subprocess: trace + lower + compile of the
jitted init and advance, ahead of time, nothing executed), peak resident
memory and the machine's core count.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _setup(suite: str, batch: int, chunk: int, reads_obs: bool = False, config=None):
    """(Rollout of ``log_replay`` under ``config`` (default ``SimConfig()``), the first ``batch``
    scenarios of ``suite`` cycled). The policy is found by name, so the code measured is that of
    whichever ``drivee2e_jax`` is imported (``scoring_views.py`` times another checkout this way)."""
    import jax
    import jax.numpy as jnp

    from drivee2e_jax.policy import load_policy, resolve_policy_path
    from drivee2e_jax.rollout import Rollout
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.sim import SimConfig, Simulator

    packed = load_suite(suite).pack(None)
    n = len(packed.meta)
    rows = [i % n for i in range(batch)]
    scn = jax.tree_util.tree_map(jnp.asarray, packed.select(rows).scenario)
    pol = load_policy(resolve_policy_path("log_replay"))
    if reads_obs:
        from drivee2e_jax.rollout import LogReplay

        class ReadsObservation(LogReplay):
            """``log_replay`` that also reads every vector-observation leaf (adds 0 x their sum
            to the throttle), so XLA cannot leave the observation out of the step."""

            name = "log_replay_reads_obs"

            def act(self, params, obs, state, key):
                c, state = super().act(params, obs, state, key)
                total = sum(jnp.sum(jnp.asarray(x, jnp.float32))
                            for x in jax.tree_util.tree_leaves(obs.replace(privileged=None)))
                return c.replace(throttle=c.throttle + 0.0 * total), state

        pol = ReadsObservation()
    ro = Rollout(Simulator(config or SimConfig()), pol, None, chunk=chunk)
    return ro, scn


def compile_probe(suite: str, batch: int, chunk: int) -> dict:
    """Trace + compile init and advance once, ahead of time (in this fresh
    process), without executing them; from a warm persistent cache the
    compile step is a cache load. Reports seconds."""
    import jax

    ro, scn = _setup(suite, batch, chunk)
    init_s, advance_s = compile_ahead(ro, scn, jax.random.split(jax.random.PRNGKey(0), batch))
    return {"compile_init_s": init_s, "compile_s": advance_s}


def compile_ahead(ro, scn, keys) -> tuple[float, float]:
    """Trace, lower and compile ``ro``'s programs ahead of time without running
    them: (seconds for ``init``'s two, seconds for ``advance``)."""
    t0 = time.perf_counter()
    programs = ro.lower_init(scn, keys)
    for program in programs:
        program.compile()
    t1 = time.perf_counter()
    ro.advance.lower(scn, programs[-1].out_info).compile()  # carry shapes: what init returns
    return t1 - t0, time.perf_counter() - t1


def measure(suite: str, batch: int, chunk: int, steps: int | None, reads_obs: bool = False, config=None) -> dict:
    """Throughput of ``_setup``'s rollout over ``steps`` (default the log length), timed after a
    compiled warm-up chunk. ``scenario_steps_per_s`` counts the reset (``reset_s``: the
    per-episode constants, the first observation) and the steps; ``steps_only_per_s`` the
    steps alone, as Waymax's bare-step figure does."""
    import jax
    import numpy as np

    ro, scn = _setup(suite, batch, chunk, reads_obs, config)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    carry = ro.init(scn, keys)
    carry, _ = ro.advance(scn, carry)  # warm-up: compile
    jax.block_until_ready(carry)
    total = steps or int(scn.tracks.valid.shape[-1]) - 1
    n_chunks = max(1, total // chunk)
    t0 = time.perf_counter()
    carry = jax.block_until_ready(ro.init(scn, keys))  # the reset counts: it is part of every episode
    t1 = time.perf_counter()
    for _ in range(n_chunks):
        carry, log = ro.advance(scn, carry)
    jax.block_until_ready(carry)
    wall = time.perf_counter() - t0
    step_wall = time.perf_counter() - t1
    sim_steps = n_chunks * chunk
    # Valid agents at each simulated log step (dt_sim == dt_log here).
    valid = np.asarray(scn.tracks.valid)[:, :, 1 : sim_steps + 1]
    agent_steps = int(valid.sum())
    return {
        "batch": batch,
        "agents": int(scn.tracks.valid.shape[1]),
        "steps": sim_steps,
        "wall_s": wall,
        "scenario_steps_per_s": batch * sim_steps / wall,
        "reset_s": wall - step_wall,
        "steps_only_per_s": batch * sim_steps / step_wall,
        "agent_steps_per_s": agent_steps / wall,
        "mean_valid_agents": float(valid.sum() / (batch * sim_steps)),
    }


def mlp_sensor_policy(hidden: int = 64, reads: tuple[str, ...] = ("bev", "lidar"), pool: str = "bits"):
    """A small MLP over the packed BEV (per-channel occupancy of 8 x 8 pooled
    cells) and the LiDAR range image (per-column minimum over channels),
    random weights: the stand-in policy of ``sweep_bev_lidar``. ``reads``:
    the sensors it declares and reads (a subset: for cost breakdowns).
    ``pool``: ``bits`` pools the packed words directly (``bev.pool_bits``, the
    documented fast path), ``float`` unpacks a (H, W, C) float image first
    (same features, ~17x the pooling cost)."""
    import jax
    import jax.numpy as jnp

    from drivee2e_jax.observe.bev import BevConfig, pool_bits, unpack_bits
    from drivee2e_jax.policy import StatelessPolicy
    from drivee2e_jax.types import Controls

    n_ch = len(BevConfig().channels)

    class MLPSensors(StatelessPolicy):
        name = "mlp_sensors"
        required_sensors = tuple(reads)

        def features(self, obs):
            parts = []
            if "bev" in reads and pool == "bits":
                h, w = obs.bev.shape
                parts.append(pool_bits(obs.bev, n_ch, h // 8, w // 8).reshape(-1))
            elif "bev" in reads:
                img = unpack_bits(obs.bev, n_ch)  # (H, W, C)
                h, w, c = img.shape
                parts.append(img.reshape(8, h // 8, 8, w // 8, c).mean(axis=(1, 3)).reshape(-1))
            if "lidar" in reads:
                parts.append(obs.lidar.min(axis=0) / 85.0)
            return jnp.concatenate([*parts, obs.ego])

        def init(self, key, obs):
            d = self.features(obs).shape[0]
            k1, k2 = jax.random.split(key)
            return {"w1": jax.random.normal(k1, (d, hidden)) / jnp.sqrt(d), "b1": jnp.zeros(hidden),
                    "w2": 0.1 * jax.random.normal(k2, (hidden, 3)), "b2": jnp.zeros(3)}

        def act(self, params, obs, policy_state, key):
            h = jnp.tanh(self.features(obs) @ params["w1"] + params["b1"])
            o = h @ params["w2"] + params["b2"]
            return Controls(throttle=jax.nn.sigmoid(o[0]), brake=jax.nn.sigmoid(o[1]) * 0.1,
                            steer=jnp.tanh(o[2]) * 0.1), policy_state

    return MLPSensors()


def sweep_bev_lidar(suite_name: str, chunk: int, steps: int | None, batch: int | None) -> dict:
    """The full-suite sweep with BEV + LiDAR and the MLP policy."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from drivee2e_jax.eval.closedloop import init_params, with_policy_sensors
    from drivee2e_jax.observe import sensors
    from drivee2e_jax.rollout import Rollout, balanced_chunk
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.sim import SimConfig, Simulator

    suite = load_suite(suite_name)
    packed = suite.pack(None)
    if batch is not None:
        packed = packed.select(np.arange(min(batch, len(packed))))
    pol = mlp_sensor_policy()
    cfg = with_policy_sensors(SimConfig(), pol)
    t0 = time.perf_counter()
    assets = sensors.build_assets(packed, cfg.sensors, suite.maps)
    raster_s = time.perf_counter() - t0
    scn = jax.tree_util.tree_map(jnp.asarray, packed.scenario)
    b = len(packed)
    sim = Simulator(cfg)
    keys = jax.random.split(jax.random.PRNGKey(0), b)
    params = init_params(pol, sim, scn, keys[0], assets)
    if jax.local_device_count() > 1:  # --host-devices: one batch shard per CPU device (thread)
        from drivee2e_jax.rollout import shard_rollout_inputs

        scn, keys, assets = shard_rollout_inputs(scn, keys, assets)
    # The episode length (the longest log), in evened-out chunks as ``bench`` runs it.
    total = steps or int(np.max(np.asarray(jax.vmap(sim.episode_steps)(packed.scenario))))
    chunk = balanced_chunk(total, chunk)
    ro = Rollout(sim, pol, params, chunk=chunk, assets=assets)
    compile_s = sum(compile_ahead(ro, scn, keys))
    carry = ro.init(scn, keys)
    carry, _ = ro.advance(scn, carry)  # runs the compiled chunk once (jit cache), then restart
    jax.block_until_ready(carry)
    carry = ro.init(scn, keys)
    n_chunks = -(-total // chunk)
    load_before = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(n_chunks):
        carry, _ = ro.advance(scn, carry)
    jax.block_until_ready(carry)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    # The machine may be shared: the load around the timed loop and its
    # process CPU time say how much of the wall was ours.
    return {"config": "sweep_bev_lidar", "suite": suite_name, "batch": b, "steps": n_chunks * chunk,
            "bev": "128x128", "lidar": "64x360", "devices": jax.local_device_count(), "wall_s": wall, "cpu_s": cpu,
            "compile_s": compile_s, "raster_s": raster_s, "scenario_steps_per_s": b * n_chunks * chunk / wall,
            "raster_mb": assets.raster.nbytes / 2**20, "load_1min_before": load_before,
            "load_1min_after": os.getloadavg()[0]}


def _probe_subprocess(suite, batch, chunk, cache_dir) -> dict:
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(cache_dir), DRIVEE2E_PERSISTENT_CACHE="1")
    cmd = [sys.executable, __file__, "--_probe", "--suite", suite, "--batches", str(batch), "--chunk", str(chunk)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _enable_persistent_cache():
    import jax

    d = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if d:
        jax.config.update("jax_compilation_cache_dir", d)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


WAYMAX_STEP = ROOT.parent / "shared" / "anchors" / "waymax" / "waymax_step.py"


def _json_lines(cmd: list[str], env: dict | None = None) -> list[dict]:
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed (exit {proc.returncode}): {proc.stderr.strip()[-1500:]}")
    return [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]


def against_waymax(args, batches: list[int]) -> int:
    """The side-by-side ratio: for each B, ``--rounds`` interleaved rounds of
    (this project's state-only configurations in a fresh process, Waymax's
    bare ``env.step`` in a fresh process), the 1-minute load before each, and
    the best of each side. Waymax runs ``WAYMAX_STEP`` (80 steps of 128
    objects in one ``lax.scan``, median of 3) with PYTHONPATH = the ``stub``
    folder next to the venv ``setup.sh`` made."""
    py = Path(args.against_waymax)
    if not py.is_file():
        raise SystemExit(f"--against-waymax: {py} is not a file; expected the Python of the Waymax venv "
                         "(bash ../shared/anchors/waymax/setup.sh <waymax git dir> ../wmx makes ../wmx/venv/bin/python)")
    if not WAYMAX_STEP.is_file():
        raise SystemExit(f"--against-waymax: {WAYMAX_STEP} is missing; expected ../shared/anchors/waymax beside the project")
    stub = Path(os.path.abspath(py)).parents[2] / "stub"  # the venv python is a symlink: do not resolve it
    wenv = dict(os.environ, PYTHONPATH=str(stub))
    configs = [c for c in args.configs.split(",") if c in ("state_only", "state_obs")] or ["state_only"]
    best: dict[tuple[str, int], float] = {}
    for b in batches:
        for r in range(args.rounds):
            load = os.getloadavg()[0]
            ours = _json_lines([sys.executable, __file__, "--configs", ",".join(configs), "--batches", str(b),
                                "--no-compile", "--json", "--suite", args.suite, "--chunk", str(args.chunk)]
                               + (["--steps", str(args.steps)] if args.steps else []))
            wload = os.getloadavg()[0]
            theirs = _json_lines([str(py), str(WAYMAX_STEP), str(b)], env=wenv)[-1]
            rows = [{"round": r + 1, "side": o["config"], "batch": b, "scenario_steps_per_s": round(o["scenario_steps_per_s"]),
                     "load_1min_before": round(load, 2), "reset_s": round(o["reset_s"], 2),
                     "steps_only_per_s": round(o["steps_only_per_s"])} for o in ours]
            rows.append({"round": r + 1, "side": "waymax_bare_step", "batch": b,
                         "scenario_steps_per_s": round(theirs["scenario_steps_per_s"]), "load_1min_before": round(wload, 2)})
            for row in rows:
                key = (row["side"], b)
                best[key] = max(best.get(key, 0.0), row["scenario_steps_per_s"])
                print(json.dumps(row) if args.json else
                      f"round {row['round']}  B={b:<4} {row['side']:<17} {row['scenario_steps_per_s']:>8,} scenario-steps/s"
                      f"  load {row['load_1min_before']}"
                      + (f"  (reset {row['reset_s']} s; steps alone {row['steps_only_per_s']:,})" if "reset_s" in row else ""),
                      flush=True)
        w = best[("waymax_bare_step", b)]
        for c in configs:
            ratio = best[(c, b)] / w
            print(json.dumps({"ratio": c, "batch": b, "best": best[(c, b)], "waymax_best": w, "ratio_vs_waymax": round(ratio, 3)})
                  if args.json else f"B={b}: {c} best {best[(c, b)]:,.0f} / Waymax best {w:,.0f} = {ratio:.2f}x", flush=True)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--suite", default="twin15")
    ap.add_argument("--batches", default="1,64,800", help="comma-separated batch sizes (default 1,64,800)")
    ap.add_argument("--chunk", type=int, default=50, help="steps per compiled advance (default 50)")
    ap.add_argument("--steps", type=int, default=None, help="simulated steps (default: the episode length, Simulator.episode_steps)")
    ap.add_argument("--no-compile", action="store_true", help="skip the cold/cached compile probes")
    ap.add_argument("--json", action="store_true", help="one JSON object per line")
    ap.add_argument("--configs", default="state_only,sweep_bev_lidar",
                    help="comma-separated configurations (default state_only,sweep_bev_lidar)")
    ap.add_argument("--sweep-batch", type=int, default=None,
                    help="sweep_bev_lidar: only the first N scenarios (default: the whole suite)")
    ap.add_argument("--host-devices", type=int, default=None,
                    help="sweep_bev_lidar: split the batch over N XLA CPU devices, one thread each "
                         "(XLA_FLAGS=--xla_force_host_platform_device_count=N; default: one device)")
    ap.add_argument("--against-waymax", metavar="PY", default=None,
                    help="also time Waymax's bare env.step with this Python (the venv made by "
                         "../shared/anchors/waymax/setup.sh, e.g. ../wmx/venv/bin/python): both sides run --rounds "
                         "times, interleaved, each in a fresh process, at the same B; prints best-of ratios")
    ap.add_argument("--rounds", type=int, default=2, help="--against-waymax: interleaved rounds (default 2)")
    ap.add_argument("--_probe", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.host_devices:
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                                   + f" --xla_force_host_platform_device_count={args.host_devices}").strip()
    batches = [int(b) for b in args.batches.split(",")]
    if args.against_waymax:
        return against_waymax(args, batches)

    if args._probe:
        _enable_persistent_cache()
        print(json.dumps(compile_probe(args.suite, batches[0], args.chunk)))
        return 0

    from drivee2e_jax.scenario import load_suite

    load_suite(args.suite).pack(None)  # build the suite cache outside the timings
    configs = args.configs.split(",")
    state_configs = [c for c in ("state_only", "state_obs", "state_idm") if c in configs]
    for config, b in ((c, b) for c in state_configs for b in batches):
        row = {"config": config, "suite": args.suite}
        if not args.no_compile and config == "state_only":
            with tempfile.TemporaryDirectory() as cache:
                cold = _probe_subprocess(args.suite, b, args.chunk, cache)
                warm = _probe_subprocess(args.suite, b, args.chunk, cache)
            row.update(compile_s=round(cold["compile_s"] + cold["compile_init_s"], 3),
                       compile_cached_s=round(warm["compile_s"] + warm["compile_init_s"], 3))
        sim_config = None
        if config == "state_idm":
            from drivee2e_jax.sim import SimConfig

            sim_config = SimConfig(agents="idm")
        m = measure(args.suite, b, args.chunk, args.steps, reads_obs=config == "state_obs", config=sim_config)
        row.update({k: (round(v, 3) if isinstance(v, float) else v) for k, v in m.items()})
        row["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        row["cores"] = os.cpu_count()
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print(
                f"{row['config']:<11} B={b:<4} A={row['agents']:<4} steps={row['steps']:<4} "
                f"{row['scenario_steps_per_s']:>10.0f} scn-steps/s {row['agent_steps_per_s']:>12.0f} agent-steps/s "
                f"compile {row.get('compile_s', float('nan')):.1f} s (cached {row.get('compile_cached_s', float('nan')):.1f} s) "
                f"rss {row['peak_rss_mb']:.0f} MB cores {row['cores']}",
                flush=True,
            )
    if "sweep_bev_lidar" in configs:
        row = sweep_bev_lidar(args.suite, args.chunk, args.steps, args.sweep_batch)
        row = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}
        row["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        row["cores"] = os.cpu_count()
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print(f"sweep_bev_lidar B={row['batch']} steps={row['steps']} wall {row['wall_s']:.1f} s "
                  f"({row['scenario_steps_per_s']:.0f} scn-steps/s) compile {row['compile_s']:.1f} s "
                  f"rss {row['peak_rss_mb']:.0f} MB cores {row['cores']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
