"""deif.bench's reductions and tables on made-up measurements (no process is started), and
the command line's argument checks."""
import os
import subprocess
import time

import pytest

from conftest import ROOT
from deif import bench, paths


def test_percentiles_interpolate_and_skip_missing():
    assert bench.pct([], 50) is None
    assert bench.pct([None, 3.0], 50) == 3.0
    assert bench.pct([1.0, 2.0, 3.0, 4.0], 50) == 2.5
    assert bench.pct([4.0, 1.0, 3.0, 2.0], 100) == 4.0
    assert bench.pct(range(101), 99) == pytest.approx(99.0)
    assert bench.median([None, 1.0, 5.0, 2.0]) == 2.0


def test_pingpong_json_of_either_shape():
    assert bench.rtt_us({"rtt_p50_us": 90.0, "rtt_p99_us": 150.0}, "p99") == 150.0
    assert bench.rtt_us({"rtt_us": {"p50": 80.0}}, "p50") == 80.0
    assert bench.rtt_us({"error": "x"}, "p50") is None


def test_log_times_and_exclusion_lines(work_dir):
    t = bench.log_unix_time("[2026-11-21 23:31:15.544] [agent-1] [warning] agent 2 lost (liveliness)")
    assert t == pytest.approx(time.mktime(time.strptime("2026-11-21 23:31:15", "%Y-%m-%d %H:%M:%S")) + 0.544)
    assert bench.log_unix_time("no timestamp") is None
    log = os.path.join(work_dir, "agent-1.log")
    with open(log, "w") as f:
        f.write("[2026-11-21 23:31:15.100] [agent-1] [info] agent 1 up\n"
                "[2026-11-21 23:31:15.544] [agent-1] [warning] agent 2 lost (liveliness); members now 3\n"
                "[2026-11-21 23:31:16.000] [agent-1] [warning] agent 3 lost (liveliness); members now 2\n")
    assert len(bench.lost_lines(log, 2)) == 1 and len(bench.lost_lines(log, 4)) == 0
    os.makedirs(os.path.join(work_dir, "logs"))
    with open(os.path.join(work_dir, "logs", "target.log"), "w") as f:
        f.write("[2026-11-21 23:31:16.085] [target] [info] done at step 300 after 1.242 s\n")
    rate = bench.target_log_rate(os.path.join(work_dir, "logs"))
    assert rate["steps"] == 300 and rate["steps_per_s"] == pytest.approx(300 / 1.242)


def test_settled_step_needs_rows_beliefs_and_the_gap():
    rows = [{"step": str(k), "rows": "3", "gap_error": str(g)}
            for k, g in [(10, 0.5), (11, 0.1), (12, 0.001), (13, 0.001)]]
    alive = {1: {10: 3, 11: 3, 12: 4, 13: 3}, 2: {10: 3, 11: 3, 12: 3, 13: 3}}
    assert bench.settled_step(rows, alive, 3, 9) == 13  # step 12: agent 1 still counts 4
    assert bench.settled_step(rows, alive, 3, 13) is None
    assert bench.settled_step(rows, alive, 4, 0) is None


def test_a_program_older_than_its_source_is_skipped(work_dir, monkeypatch):
    monkeypatch.setenv("DEIF_BUILD_DIR", work_dir)
    exe, why = bench.bench_program("core_bench")
    assert exe is None and "not found" in why
    os.makedirs(os.path.join(work_dir, "bin"))
    path = os.path.join(work_dir, "bin", "core_bench")
    with open(path, "w") as f:
        f.write("")
    source = os.path.join(ROOT, "bench", "core_bench.cpp")
    if os.path.exists(source):
        os.utime(path, (0, 0))
        exe, why = bench.bench_program("core_bench")
        assert exe is None and "older than bench/core_bench.cpp" in why
    os.utime(path, None)
    assert bench.bench_program("core_bench") == (path, None)


def made_up_results():
    lock = {"4": {"n": 4, "steps": 300, "ok": True, "last_step": 300, "final_agents": 4,
                  "latency_ms": {"p50": 1.0, "p99": 2.0}, "steps_per_s": 500.0,
                  "steady": {"steps_per_s": 480.0, "cpu_s_per_step": 0.002},
                  "discovery_s": {"first_fused_all": 1.1}, "rss_mb": {"agent_median": 18.0, "agent_max": 19.0},
                  "pss_mb": {"agent_median": 6.0, "agent_max": 6.5}},
            "64": {"n": 64, "steps": 60, "ok": True, "last_step": 60, "final_agents": 64,
                   "timed_out_s": None, "steady": {"steps_per_s": 3.0, "cpu_s_per_step": 0.026},
                   "discovery_s": {"first_fused_all": 1.5},
                   "rss_mb": {"agent_median": 21.0, "agent_max": 22.0},
                   "pss_mb": {"agent_median": 9.0, "agent_max": 20.5}}}
    return {"pingpong": {"shm": [{"rtt_p50_us": 100.0, "rtt_p99_us": 200.0}],
                         "udp": [{"rtt_p50_us": 130.0, "rtt_p99_us": 260.0}], "shm_p50_us_median": 100.0},
            "lockstep": lock,
            "failure": {"n": 4, "kills": 3, "lease_s": 0.4,
                        "exclusion_s": {"p50": 0.38, "p99": 0.39, "max": 0.39, "samples": 9, "not_seen": 0},
                        "steps_to_1deg": {"p50": 10, "max": 11, "samples": 3}},
            "wire": {"rows": [{"n": 2, "bytes_per_step": 4000.0, "bytes_per_agent_per_step": 2000.0,
                               "packets_per_step": 17.0, "bytes_per_step_over_n2": 1000.0,
                               "steps_per_s_udp": 600.0}]},
            "core": {"rows": [{"name": "BM_DeifAgentStep/N:4/model:0", "cpu_ns": 1000.0}]},
            "skipped": {"pingpong": "made up"}}


def test_goals_and_tables_from_made_up_figures():
    res = made_up_results()
    bench.evaluate_goals(res)
    goals = {g["goal"]: g["met"] for g in res["goals"]["rows"]}
    assert res["ratio_4_agent_latency_to_shm_rtt"] == pytest.approx(10.0)  # 1 ms against 100 us
    assert goals == {"4 agents: step latency p50 <= 3 x SHM round trip p50": "no",
                     "4 agents: >= 2500 steps/s": "no",
                     "64 agents run the lock-step scenario to the end (default config)": "yes",
                     "64 agents: >= 30 steps/s": "no",
                     # 26 ms of CPU a step over 65 processes
                     "64 agents: CPU per agent per step <= 0.5 ms": "yes",
                     "64 agents: launch to the first step fused by all <= 2 s": "yes",
                     "kill-to-exclusion p99 < 0.5 s": "yes",
                     # 22 MB at N = 64
                     "resident memory <= 20 MB per agent (every N)": "no",
                     # 20.5 MB at N = 64
                     "proportional memory (PSS) <= 20 MB per agent (every N)": "no"}
    table = bench.make_table(res)
    for heading in ("Raw floor", "Lock-step", "Goals", "Failure detection", "Wire cost", "Core micro-benchmarks"):
        assert f"**{heading}" in table, heading
    assert "| 4 | 300/300 ok | 500 | 480 |" in table
    assert "| 18.0 / 19.0 | 6.0 / 6.5 |" in table
    assert "| BM_DeifAgentStep (model:0) | 1.00 |" in table
    assert "_pingpong: skipped: made up_" in table


def test_lockstep_table_sets_the_other_membership_beside_the_default():
    """Over the tree the lock-step section runs the membership auto does not pick (all_pairs
    from 28 agents on, roll_call below) beside the default; each is its own row after it."""
    assert bench.other_membership(16 + 4) == "network.membership=roll_call"
    assert bench.other_membership(64) == "network.membership=all_pairs"
    res = made_up_results()
    res["lockstep_other_membership"] = {"64": dict(res["lockstep"]["64"], last_step=59)}
    table = bench.make_table(res)
    rows = [line for line in table.splitlines() if line.startswith("| 64")]
    assert len(rows) == 2 and rows[0].startswith("| 64 | 60/60") and \
        rows[1].startswith("| 64, membership all_pairs | 59/60"), rows


def test_a_section_that_did_not_run_leaves_no_goal():
    res = {"failure": made_up_results()["failure"]}
    bench.evaluate_goals(res)
    assert [g["goal"] for g in res["goals"]["rows"]] == ["kill-to-exclusion p99 < 0.5 s"]


def test_results_go_to_an_ignored_folder_only():
    assert bench.RESULTS_DIR == os.path.join(ROOT, "bench", "results")
    with open(os.path.join(ROOT, ".gitignore")) as f:
        assert "/bench/results/" in f.read().split()


@pytest.mark.parametrize("args,message", [(["--only", "nonsense"], "nonsense"), (["--agents", "2,x"], "--agents")])
def test_command_line_refuses_bad_arguments(args, message):
    p = subprocess.run([paths.PYTHON, os.path.join(ROOT, "scripts", "deif-bench"), *args],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert p.returncode == 2 and message in p.stdout


def test_network_table_from_made_up_figures():
    from deif import bench_network
    row = {"ok": True, "steps": 100, "rows_written_fraction": 1.0, "longest_disagreement_steps": 0,
           "false_exclusions": 0, "steps_per_s_target": 10.0}
    net = {"steps": 100, "rows": [
        dict(row, name="realtime 10 Hz, 0% loss", agreement_fraction=1.0, rmse_m=0.02),
        dict(row, name="realtime 10 Hz, 10% loss", agreement_fraction=0.98, rmse_m=0.03,
             longest_disagreement_steps=2),
        dict(row, name="realtime 10 Hz, host 3 cut off for 3 s", agreement_fraction=0.8, rmse_m=0.3,
             partition={"cut_at_step": 60, "healed_at_step": 90, "agree_after_heal_s": 0.2,
                        "full_ring_after_heal_s": 0.1})],
        "sim": {"0.1": {"rmse_mean": 0.025, "rmse_se": 0.001, "agreement_mean": 0.99, "seeds": 5}}}
    table = bench_network.make_table(net)
    # 0.03 / 0.02 against the loss-free run; none for the cut-off run (no ranges there)
    assert "| realtime 10 Hz, 10% loss | ok | 100.0% | 98.0% | 2 | 0.0300 | 1.50 | 0 | 10 |" in table
    assert "| 0.3000 | - |" in table
    assert "agree to 1e-6 m 0.2 s after the heal" in table
    assert "| 10% | 0.0250 +- 0.0010 | 0.0300 | 99.0% | 98.0% |" in table


def test_realtime_table_takes_the_median_agent_delivery_delays():
    from deif import bench_network, launcher
    counters = {"target": {"delivery_ms": {"state": {"p50": 99.0, "p99": 99.0}}},
                "agent_1": {"delivery_ms": {"range": {"p50": 1.0, "p99": 9.0}}},
                "agent_2": {"delivery_ms": {"range": {"p50": 3.0, "p99": 5.0},
                                            "relay_down": {"p50": 7.0, "p99": 20.0}}},
                "agent_3": {"delivery_ms": {"range": {"p50": 2.0, "p99": 30.0}}},
                "agent_4": {}}
    # The target's states are not the agents'; each quantile's median on its own.
    assert launcher.median_delivery_ms(counters) == {"range": [2.0, 9.0], "relay_down": [7.0, 20.0]}
    row = {"n": 3, "steps": 10, "ok": True, "rows_written_fraction": 1.0, "complete_fraction": 1.0,
           "agreement_fraction": 1.0, "final_agents": 3, "rmse_m": 0.01,
           "delivery_ms": launcher.median_delivery_ms(counters)}
    assert "| 0.0100 | range 2.0 / 9.0, relay_down 7.0 / 20.0 |" in bench_network.realtime_table([row])


def test_a_step_is_complete_only_if_every_agent_wrote_it_complete():
    from deif import bench_network
    rows = {1: [{"step": "1", "complete": "1"}, {"step": "2", "complete": "1"}, {"step": "3", "complete": "1"}],
            # step 2 written incomplete, step 3 not written at all
            2: [{"step": "1", "complete": "1"}, {"step": "2", "complete": "0"}]}
    assert bench_network.complete_steps(rows, 3) == {1}
    assert bench_network.complete_steps({1: rows[1]}, 3) == {1, 2, 3}
    row = {"n": 2, "steps": 3, "ok": True, "rows_written_fraction": 5 / 6, "complete_fraction": 0.8,
           "steps_complete_fraction": 1 / 3, "first_incomplete_steps": [2, 3],
           "agreement_fraction": 1.0, "final_agents": 2, "rmse_m": 0.01}
    assert "| 2 | ok | 83.3% | 80.0% | 33.3% (2 3) | 100.0% |" in bench_network.realtime_table([row])
    # The agents' CPU policy names the row: the same N runs under both (run_realtime_scale)
    table = bench_network.realtime_table([dict(row, agent_sched="batch"), dict(row, agent_sched="normal")])
    assert "| 2 (SCHED_BATCH) | ok |" in table and "| 2 (SCHED_OTHER) | ok |" in table


def test_runs_that_did_not_finish_well_are_kept(work_dir):
    import json
    def run_folder(name, summary):
        d = os.path.join(work_dir, "runs", name)
        os.makedirs(os.path.join(d, "logs"))
        open(os.path.join(d, "config.yaml"), "w").close()
        if summary is not None:
            with open(os.path.join(d, "summary.json"), "w") as f:
                json.dump(summary, f)
    run_folder("good", {"ok": True})
    run_folder("failed", {"ok": False})
    run_folder("unfinished", None)  # the launcher never wrote its summary
    dest = os.path.join(work_dir, "kept")
    kept = bench.keep_failed_runs(os.path.join(work_dir, "runs"), dest)
    assert sorted(os.path.basename(k) for k in kept) == ["failed", "unfinished"]
    assert sorted(os.listdir(dest)) == ["failed", "unfinished"]
    assert os.path.isdir(os.path.join(dest, "failed", "logs"))
    assert os.listdir(os.path.join(work_dir, "runs")) == ["good"]
    assert bench.keep_failed_runs(os.path.join(work_dir, "runs"), dest) == []


def test_disagreement_runs_are_maximal_runs_of_steps_above_1e_6():
    from deif import bench_network
    steps = [{"step": str(k), "max_disagreement": str(v)}
             for k, v in enumerate([0, 1e-3, 2e-6, 0, 1e-7, 5e-3, 0], start=1)]
    assert bench_network._disagreement_runs(steps) == [2, 1]


def test_hostile_medians_slowdowns_and_goal_from_made_up_figures():
    from deif import bench_hostile
    run = {"ok": True, "anees": 1.1, "rmse_m": 0.02, "sent": 12}
    out = {"reps": 3, "steps": 8000, "runs": {
        "none": [dict(run, steps_per_s=v) for v in (790.0, 800.0, 900.0)],
        "ranges": [dict(run, steps_per_s=v) for v in (700.0, 400.0, 760.0)],
        "flood": [dict(run, steps_per_s=v, sent=30000) for v in (300.0, 200.0, 500.0)]}}
    h = bench_hostile.summarize(out)
    assert h["medians"]["ranges"]["slowdown"] == 800.0 / 700.0
    assert h["medians"]["flood"]["slowdown"] == 800.0 / 300.0
    assert h["goal"]["worst"] == 800.0 / 300.0 and not h["goal"]["met"]
    table = bench_hostile.make_table(h)
    assert "| flood | 30000 | 300 | 2.67 | 1.10 | 0.0200 | 3/3 |" in table
    assert "worst slowdown 2.67: **not met**" in table


def test_memory_of_a_live_process_and_of_a_gone_one():
    m = bench.proc_memory_kb(os.getpid())
    # PSS is the private pages plus a share of the shared ones, so never below them.
    assert m is not None and 0 < m["private"] <= m["pss"]
    assert m["pss"] <= bench.proc_hwm_kb(os.getpid())
    assert bench.proc_memory_kb(2 ** 22 + 7) is None


def test_security_table_with_protection_levels_from_made_up_figures():
    from deif import bench_security
    med = {key: {"plain": None, "secure": None, "ratio": None} for key, *_ in bench_security.FIGURES}
    med["steps_per_s"] = {"plain": 800.0, "secure": 250.0, "ratio": 250.0 / 800.0}
    med["runs_ok"] = {"plain": 1, "secure": 1, "submessages-none": 1, "no-crypto": 0}
    sec = {"reps": 1, "medians": {"4 shm": med},
           "levels": {"4 shm": {"submessages-none": {"steps_per_s": 400.0, "cpu_ms_per_step": 4.5,
                                                     "runs_ok": 1},
                                "no-crypto": {"steps_per_s": None, "runs_ok": 0}}},
           "goal": {"name": "secure lock-step at N = 4 (shm) within 1.5x of plain",
                    "plain_over_secure": 3.2, "met": False}}
    table = bench_security.make_table(sec)
    assert "| 4 shm | lock-step rate [steps/s] | 800 | 250 | 0.31 |" in table
    assert "(--submessages none) | 400 | 2.00 | 4.50 | - | 1/1 |" in table
    assert "(measurement only) | - | - | - | - | 0/1 |" in table
    assert "**not met**" in table


def test_alltoall_table_sets_the_lockstep_beside_its_floor():
    res = {"alltoall": {"4": {"n": 4, "runs_ok": 3, "runs": 3, "rounds_per_s": 4000.0,
                              "cpu_ms_per_round": 0.5, "cpu_us_per_delivery": 41.7, "errors": []},
                        "64": {"n": 64, "runs_ok": 0, "runs": 1, "rounds_per_s": None,
                               "cpu_ms_per_round": None, "cpu_us_per_delivery": None,
                               "errors": ["exit -6: made up"]}},
           "lockstep": {"4": {"steps_per_s": 1000.0}}}
    table = bench.make_table(res)
    assert "**All-to-all floor" in table
    # the lock-step runs at a quarter of the bare exchange
    assert "| 4 | 4000.0 | 0.50 | 42 | 1000.0 | 0.25 | 3/3 |" in table
    assert "| 64 | - | - | - | - | - | 0/1 |" in table


def test_deliveries_of_each_exchange_count_every_sample_once():
    assert bench.deliveries(4) == 12
    # 4 groups of 4: 4 x 12 within the groups, and each group's sample reaches the 15 others
    assert bench.deliveries(16, "relay", 4) == 48 + 60
    # groups of 4, 4 and 2: 12 + 12 + 2 within, 3 x 9 relayed
    assert bench.deliveries(10, "relay", 4) == 26 + 27
    assert bench.deliveries(64, "tree", 4) == 126


def test_exchanges_table_sets_each_exchange_beside_the_all_to_all_of_its_n():
    res = {"alltoall": {"16": {"n": 16, "runs_ok": 3, "runs": 3, "rounds_per_s": 100.0,
                               "cpu_ms_per_round": 10.0, "cpu_us_per_delivery": 41.7, "errors": []}},
           "exchanges": [{"n": 16, "mode": "tree", "size": 4, "runs_ok": 3, "runs": 3, "rounds_per_s": 450.0,
                          "cpu_ms_per_round": 1.5, "cpu_us_per_delivery": 50.0, "deliveries_per_round": 30,
                          "errors": []},
                         {"n": 16, "mode": "relay", "size": 4, "runs_ok": 2, "runs": 3, "rounds_per_s": 160.0,
                          "cpu_ms_per_round": 4.0, "cpu_us_per_delivery": 37.0, "deliveries_per_round": 108,
                          "errors": ["exit 1: made up"]},
                         {"n": 64, "mode": "tree", "size": 4, "runs_ok": 0, "runs": 1, "rounds_per_s": None,
                          "cpu_ms_per_round": None, "cpu_us_per_delivery": None, "deliveries_per_round": None,
                          "errors": ["exit 1: made up"]}]}
    table = bench.make_table(res)
    assert "**Exchanges that scale" in table
    assert "| 16 | relay groups of 4 | 108 | 160.0 | 1.6 | 4.00 | 37 | 2/3 |" in table
    assert "| 16 | tree, fan-out 4 | 30 | 450.0 | 4.5 | 1.50 | 50 | 3/3 |" in table
    # no all-to-all at 64 in this invocation: no ratio
    assert "| 64 | tree, fan-out 4 | - | - | - | - | - | 0/1 |" in table
