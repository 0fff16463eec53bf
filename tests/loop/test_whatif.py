"""`bmctl whatif`: ensembles of schedules compared; bad input."""

import csv

import pytest

from bmctl.cli import main

from ..conftest import ROOT, card_path

LAB = str(card_path("alni-1to1-300rpm-lab"))


@pytest.mark.slow
def test_whatif_compares_schedules(tmp_path, capsys):
    a = tmp_path / "a.toml"
    a.write_text('name = "hot"\n[[segment]]\nhours = 2\nrpm = 400\n', encoding="utf-8")
    b = tmp_path / "b.toml"
    b.write_text('name = "gentle"\n[[segment]]\nhours = 1\nrpm = 250\n[[segment]]\nhours = 1\nrpm = 0\n', encoding="utf-8")
    rc = main(["whatif", LAB, str(a), str(b), "--seeds", "2", "--particles", "500", "--out", str(tmp_path / "o")])
    assert rc == 0, capsys.readouterr().err
    rows = list(csv.DictReader((tmp_path / "o" / "whatif.csv").read_text(encoding="utf-8").splitlines()))
    assert [r["schedule"] for r in rows] == ["hot", "gentle"]
    hot, gentle = rows
    # physics the comparison must show: more power -> hotter and more energy
    assert float(hot["energy_kj"]) > float(gentle["energy_kj"]) > 0
    assert float(hot["peak_temperature_c"]) > float(gentle["peak_temperature_c"])
    assert float(hot["final_s_mean_um_q05"]) <= float(hot["final_s_mean_um"]) <= float(hot["final_s_mean_um_q95"])
    for png in ("whatif_moments.png", "whatif_final.png"):
        assert (tmp_path / "o" / png).read_bytes()[:4] == b"\x89PNG"


def test_whatif_bad_input(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[segment]]\nhours = 1\nrpm = 9000\n", encoding="utf-8")
    rc = main(["whatif", LAB, str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "segment[0].rpm" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
    rc = main(["whatif", LAB, str(ROOT / "scenarios" / "schedule-ramp-rest.toml"), "--seeds", "0"])
    assert rc == 2 and "--seeds" in capsys.readouterr().err
    rc = main(["whatif", LAB, str(ROOT / "scenarios" / "schedule-ramp-rest.toml"), "--workers", "-1"])
    err = capsys.readouterr().err
    assert rc == 2 and "--workers" in err and len(err.strip().splitlines()) == 1


def _two_thread_workers():
    from distributed import Client, LocalCluster

    return Client(LocalCluster(n_workers=2, processes=False, threads_per_worker=1, dashboard_address=":0",
                               silence_logs=40))


@pytest.mark.slow
def test_whatif_same_numbers_serial_and_on_two_workers(tmp_path, capsys):
    """--workers 0 (serial, in process) and a 2-worker Dask cluster write the same CSV, digit for digit."""
    from bmctl import io
    from bmctl.config import load_card
    from bmctl.parallel import close_client
    from bmctl.whatif import run_schedule_ensemble, table_rows

    sched = tmp_path / "s.toml"
    sched.write_text('name = "s"\n[[segment]]\nhours = 0.5\nrpm = 400\n[[segment]]\nhours = 0.25\nrpm = 0\n', encoding="utf-8")
    rc = main(["whatif", LAB, str(sched), "--seeds", "3", "--particles", "300", "--seed", "7", "--workers", "0",
               "--out", str(tmp_path / "serial")])
    assert rc == 0, capsys.readouterr().err
    client = _two_thread_workers()
    try:
        res = run_schedule_ensemble(load_card(LAB), "s", [(0.5, 400.0), (0.25, 0.0)], 3, 300, base_seed=7,
                                    client=client)
    finally:
        close_client(client)
    io.write_csv(tmp_path / "dask.csv", *table_rows([res]))
    assert (tmp_path / "dask.csv").read_text(encoding="utf-8") == (tmp_path / "serial" / "whatif.csv").read_text(encoding="utf-8")


@pytest.mark.slow
def test_whatif_member_k_is_the_plant_seeded_by_child_k():
    """Member k is the plant drawn from child k of SeedSequence(base_seed), run open loop; the
    ensembles of neighbouring seeds share no plant."""
    import numpy as np

    from bmctl.config import load_card
    from bmctl.loop import run_open_loop
    from bmctl.plant.plant import Plant
    from bmctl.whatif import run_schedule_ensemble

    card = load_card(LAB)
    segs = [(0.5, 350.0), (0.25, 0.0)]
    res = run_schedule_ensemble(card, "x", segs, 2, 300, base_seed=5)
    for k in range(2):
        plant = Plant(card, np.random.default_rng(np.random.SeedSequence(5).spawn(2)[k]), 300)
        recs = []
        run_open_loop(plant, segs, 0.25, lambda t, mill: recs.append(mill.moments()))
        assert np.array_equal(res.traj["s_mean_um"][k], [m["s_mean_um"] for m in recs])
        assert np.array_equal(res.traj["r_std"][k], [m["r_std"] for m in recs])
        assert np.array_equal(res.final_s_um[k * 300:(k + 1) * 300], plant.s * 1e6)
    assert not np.array_equal(res.traj["s_mean_um"][0], res.traj["s_mean_um"][1])
    nxt = run_schedule_ensemble(card, "x", segs, 2, 300, base_seed=6)
    assert not any(np.array_equal(a, b) for a in res.traj["s_mean_um"] for b in nxt.traj["s_mean_um"])


def _short_schedule(tmp_path):
    sched = tmp_path / "s.toml"
    sched.write_text('name = "s"\n[[segment]]\nhours = 0.5\nrpm = 300\n', encoding="utf-8")
    return str(sched)


def test_whatif_writes_all_of_its_outputs_or_none(tmp_path, capsys, monkeypatch):
    """Ctrl-C while the first figure is saved leaves no whatif.csv beside it: the three files are one set."""
    from bmctl import io

    def interrupted(fig, path, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(io, "savefig", interrupted)
    out = tmp_path / "o"
    rc = main(["whatif", LAB, _short_schedule(tmp_path), "--seeds", "2", "--particles", "200", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 130 and len(err.strip().splitlines()) == 1, err
    assert not out.exists() or not any(out.iterdir())


def test_whatif_starts_no_more_workers_than_members(tmp_path, capsys, monkeypatch):
    """--workers 24 for 2 plants asked a 24-process cluster (24 s for a 1 s job); --workers 4096 hung the machine."""
    from bmctl import parallel

    asked = []

    def record(scheduler=None, workers=None, processes=True):
        asked.append(workers)
        return None  # serial: the same numbers (tests above)

    monkeypatch.setattr(parallel, "client_for", record)
    for workers in ("24", "4096"):
        rc = main(["whatif", LAB, _short_schedule(tmp_path), "--seeds", "2", "--particles", "200", "--workers",
                   workers, "--out", str(tmp_path / "o")])
        assert rc == 0, capsys.readouterr().err
    assert asked == [2, 2]
    cap = parallel.WORKERS_PER_CPU * parallel.default_workers()
    assert parallel.auto_workers(10**6, 1e9, workers=10**6) == cap
    assert parallel.auto_workers(100, 1e4, workers=3) == 3 and parallel.auto_workers(5, 1.0, workers=0) == 0


def _deliver_sigint():
    """SIGINT to this process, handled by Python's default handler (KeyboardInterrupt)."""
    import os
    import signal

    os.kill(os.getpid(), signal.SIGINT)


@pytest.fixture
def python_sigint():
    """Python's own SIGINT handler for the test (a test runner's worker may ignore SIGINT)."""
    import signal

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


def test_ctrl_c_while_the_local_cluster_starts_closes_it(monkeypatch, python_sigint):
    """A Ctrl-C in the middle of the start left a half-started cluster for Dask's exit handler (a
    traceback after bmctl's one line, or a 10 s wait): it is held back until the start is done, and
    the cluster is closed before the KeyboardInterrupt goes on."""
    import distributed

    from bmctl.parallel import client_for

    clusters = []
    real = distributed.Client

    def client(cluster, *args, **kwargs):
        clusters.append(cluster)
        _deliver_sigint()
        return real(cluster, *args, **kwargs)

    monkeypatch.setattr(distributed, "Client", client)
    with pytest.raises(KeyboardInterrupt):
        client_for(None, 2, processes=False)
    assert len(clusters) == 1 and clusters[0].status.name == "closed"


def test_ctrl_c_while_the_client_closes_comes_after_the_close(python_sigint):
    """A Ctrl-C in Dask's close waited 10 s for it and left the cluster open: it now comes when the close is done."""
    from bmctl.parallel import client_for, close_client

    client = client_for(None, 2, processes=False)
    cluster = client.cluster
    real_close = client.close

    def close(*args, **kwargs):
        client.close = real_close  # once: Client.__del__ closes again
        _deliver_sigint()
        return real_close(*args, **kwargs)

    client.close = close
    with pytest.raises(KeyboardInterrupt):
        close_client(client)
    assert cluster.status.name == "closed"


def test_whatif_tells_apart_two_schedules_of_one_name(tmp_path, capsys, monkeypatch):
    """Two `design` outputs both named "design-..." showed as two identical rows, curves and ticks;
    and 0.05 h printed as 0.1. Each label now names its schedule alone, everywhere it is shown."""
    from bmctl import io

    paths = []
    for folder, hours in (("A", 0.05), ("B", 0.1)):
        (tmp_path / folder).mkdir()
        p = tmp_path / folder / "schedule.toml"
        p.write_text(f'name = "design-lab"\n[[segment]]\nhours = {hours}\nrpm = 300\n', encoding="utf-8")
        paths.append(str(p))
    shown = []
    real = io.savefig

    def savefig(fig, path, **kwargs):
        for ax in fig.axes:
            leg = ax.get_legend()
            shown.append(sorted({t.get_text() for t in (leg.get_texts() if leg else [])} - {
                "mean over seeds", "95th percentile"}))
            shown.append([t.get_text() for t in ax.get_xticklabels() if t.get_text().startswith("design")])
        return real(fig, path, **kwargs)

    monkeypatch.setattr(io, "savefig", savefig)
    rc = main(["whatif", LAB, *paths, "--seeds", "1", "--particles", "100", "--out", str(tmp_path / "o")])
    out = capsys.readouterr().out
    assert rc == 0
    want = ["design-lab (A)", "design-lab (B)"]
    rows = list(csv.DictReader((tmp_path / "o" / "whatif.csv").read_text(encoding="utf-8").splitlines()))
    assert [r["schedule"] for r in rows] == want
    table = [line.split() for line in out.splitlines() if line.startswith("design-lab")]
    assert [line[:3] for line in table] == [["design-lab", "(A)", "0.05"], ["design-lab", "(B)", "0.1"]]
    assert want in shown  # legends of the moments and the final pdfs, and the peak-temperature ticks
    assert all(s in ([], want) for s in shown), shown


def _named(path, name, hours=0.05):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'name = "{name}"\n[[segment]]\nhours = {hours}\nrpm = 300\n', encoding="utf-8")
    return str(path)


def _labels(tmp_path, capsys, paths) -> list[str]:
    rc = main(["whatif", LAB, *paths, "--seeds", "1", "--particles", "100", "--out", str(tmp_path / "o")])
    assert rc == 0, capsys.readouterr().err
    return [r["schedule"] for r in csv.DictReader((tmp_path / "o" / "whatif.csv").read_text(encoding="utf-8").splitlines())]


def test_whatif_labels_never_take_or_imitate_another_schedules_name(tmp_path, capsys):
    """One file given twice (named x) and a file named `x #1` were labelled `x #1 #1`, `x #2`, `x #1 #2`;
    files a/s.toml and b/s.toml (both x) and one named `x (a)` were `x`, `x (b)`, `x (a)`, where `x (a)`
    read as a/s.toml. Each schedule named alone keeps its name; the others read like none of them."""
    s = _named(tmp_path / "s.toml", "x")
    assert _labels(tmp_path, capsys, [s, s, _named(tmp_path / "t.toml", "x #1")]) == ["x (#1)", "x (#2)", "x #1"]
    paths = [_named(tmp_path / "a" / "s.toml", "x"), _named(tmp_path / "b" / "s.toml", "x"),
             _named(tmp_path / "c.toml", "x (a)")]
    assert _labels(tmp_path, capsys, paths) == ["x [a]", "x [b]", "x (a)"]


@pytest.mark.parametrize("names,paths", [
    (["x", "x", "x #1"], None), (["x", "x", "x #1"], ["s", "s", "t"]), (["x", "x", "x (a)"], ["a/s", "b/s", "c"]),
    (["x", "x", "x (a)", "x [a]", "x {a}", "x <a>"], ["a/s", "b/s", "c", "d", "e", "f"]),
    (["x", "x", "x (#1)", "x #2", "x #1"], None), (["x", "x", "x #1", "x #1"], None),
    (["x (a)", "x", "x", "x (a)"], ["a/s", "a/s", "b/s", "b/s"])])
def test_unique_labels_are_distinct_and_no_made_label_is_a_name(names, paths):
    from bmctl.whatif import unique_labels

    labels = unique_labels(names, paths)
    assert len(set(labels)) == len(labels), labels
    alone = {n for n in names if names.count(n) == 1}
    for name, label in zip(names, labels):
        if name in alone:
            assert label == name
        else:
            assert label not in names and label.startswith(name + " "), labels


@pytest.mark.parametrize("milling", ["0.0001", "0.99999"])
def test_whatif_refuses_a_share_leaving_a_phase_under_six_seconds(tmp_path, capsys, milling):
    """0.0001 of 0.5 h mills 0.18 s, 0.99999 rests 0.018 s: under the 6 s phase, and both ran."""
    p = tmp_path / "short.toml"
    p.write_text(f"[[segment]]\nhours = 0.5\nrpm = 300\nmilling = {milling}\n", encoding="utf-8")
    rc = main(["whatif", LAB, str(p), "--seeds", "1", "--particles", "100", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"bmctl: error: {p}: segment[0].milling: ") and "6 s" in err
    assert not (tmp_path / "o").exists()
