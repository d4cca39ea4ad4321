"""The pictures say what they show: colour bars, units, every energy term, legends as drawn, labels apart.

Each figure is caught as it is saved (``Figure.savefig`` replaced) and read back through matplotlib's own
objects: what a reader would see, without comparing pixels.
"""
from __future__ import annotations

import itertools
from pathlib import Path
from types import SimpleNamespace

import matplotlib.figure
import numpy as np
import pytest

from tissue_sim_ros import render
from tissue_sim_ros.core.config import resolve_config
from tissue_sim_ros.core.resources import scene_params_file
from tissue_sim_ros.core.series import energy_total, split_remainder
from tissue_sim_ros.core.sim.scene import build_simulation
from tissue_sim_ros.core.timing import trajectories as tr


@pytest.fixture
def figures(monkeypatch):
    caught: list[matplotlib.figure.Figure] = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: caught.append(fig))
    return caught


def test_snapshots_carry_a_colour_bar_naming_the_strain_and_its_unit(figures, tmp_path):
    sim = build_simulation()
    x = sim.state.particle_q
    render.save_snapshots(tmp_path / "s.png", sim.model, [(0, x, None), (5, x, None)], tool=sim.tool)
    render.save_grasp_snapshots(tmp_path / "g.png", sim.model, [("start", x, None, None, np.zeros(0, int))],
                                tool=build_simulation(resolve_config(params_file=scene_params_file("retract"))).tool)
    for fig in figures:
        labels = [ax.get_ylabel() for ax in fig.axes]
        assert any("strain" in label and "no unit" in label for label in labels), labels


def test_energy_axes_name_their_unit():
    pbd = resolve_config().sim
    assert "kg m^2" in render.energy_label(pbd) and "not J s^2" in render.energy_label(pbd)
    for values in ({"method": "xpbd"}, {"material": "neo_hookean"}):
        assert render.energy_label(resolve_config(values).sim).endswith("[kg m^2 = J s^2]")


def test_the_energy_plot_draws_every_term_and_their_total(figures, tmp_path):
    """The demo plotted inertial + spring + area as the total of the material scenes (strain and attach left out)."""
    steps = np.arange(1, 6)
    terms = {"inertial": np.full((5, 1), 1.0), "spring": np.zeros((5, 1)), "area": np.zeros((5, 1)),
             "strain": np.full((5, 1), 10.0), "attach": np.full((5, 1), 100.0)}
    render.plot_energy(tmp_path / "e.png", steps, terms, body_names=["tissue"], ylabel="E [kg m^2]")
    ax = figures[0].axes[0]
    lines = {line.get_label(): line.get_ydata() for line in ax.get_lines()}
    np.testing.assert_array_equal(lines["total"], 111.0)
    assert {"inertial", "strain", "attach"} <= set(lines) and "spring" not in lines  # zero throughout: left out
    assert ax.get_ylabel() == "E [kg m^2]"


def test_a_per_body_table_gets_its_missing_terms_from_the_scene_sums():
    listed = {"inertial": np.array([[1.0, 2.0]]), "spring": np.zeros((1, 2)), "area": np.zeros((1, 2))}
    total = np.array([[4.0, 7.0]])
    assert set(split_remainder(listed, total, {"strain": np.array([8.0]), "attach": np.array([0.0])})) == {"strain"}
    both = split_remainder(listed, total, {"strain": np.array([5.0]), "attach": np.array([3.0])})
    np.testing.assert_array_equal(both["strain + attach"], [[3.0, 5.0]])
    one = split_remainder({"inertial": np.array([[1.0]])}, np.array([[9.0]]),
                          {"strain": np.array([5.0]), "attach": np.array([3.0])})
    np.testing.assert_array_equal(energy_total({**{"inertial": np.array([[1.0]])}, **one}), [[9.0]])


def test_the_retraction_phase_names_do_not_overlap(figures, tmp_path):
    """The names of the 0.1 s phases (close, open) were written at their starts, on top of their neighbours'."""
    ends = np.cumsum([d for _, d in tr.RETRACT_PHASES])
    starts = np.concatenate([[0.0], ends[:-1]])
    t = np.linspace(0.0, ends[-1], 371)
    terms = {"inertial": np.full_like(t, 1e-9), "strain": 1e-7 * t, "attach": 1e-8 * t}
    render.plot_grasp(tmp_path / "g.png", t, terms, np.zeros((len(t), 2)), np.zeros(len(t)), np.zeros(len(t)),
                      phases=[(float(s), name) for (name, _), s in zip(tr.RETRACT_PHASES, starts)])
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = figures[0]
    canvas = FigureCanvasAgg(fig)  # the figure was closed once saved: draw it again to measure its texts
    canvas.draw()
    renderer = canvas.get_renderer()
    names = {name for name, _ in tr.RETRACT_PHASES}
    texts = [a for a in fig.axes[0].texts if a.get_text() in names]
    assert len(texts) == len(names)
    boxes = [a.get_window_extent(renderer) for a in texts]
    offset = fig.axes[0].yaxis.get_offset_text()
    if offset.get_visible() and offset.get_text():
        boxes.append(offset.get_window_extent(renderer))
    for a, b in itertools.combinations(boxes, 2):
        assert not a.overlaps(b), (a, b)


def test_the_live_plans_legend_shows_what_is_drawn(figures, tmp_path):
    """The legend gave the mesh as a grey line (it is drawn filled in strain colours) and each speed in the
    colour of its first point's cost (the colour is the cost; the speed is the marker)."""
    from tissue_sim_ros.experiments.plan_live import draw_plan
    from tissue_sim_ros.ros.messages import encode_float64_multiarray

    def point(x, y):
        return SimpleNamespace(x=x, y=y)

    colour = SimpleNamespace(r=0.9, g=0.3, b=0.3, a=1.0)
    mesh = SimpleNamespace(ns="tissue", type=11, TRIANGLE_LIST=11, points=[point(0, 0), point(0.1, 0), point(0, 0.1)],
                           colors=[colour] * 3, color=colour)
    fields = ["angle_deg", "speed_mps", "cost", "feasible", "best"]
    rows = np.array([[-10, 0.1, 2.0, 1, 0], [-20, 0.1, 1.0, 1, 1], [-10, 0.2, 3.0, 1, 0], [-20, 0.2, 4.0, 1, 0]], float)
    costs = encode_float64_multiarray(rows, ["candidate", "field:" + ",".join(fields)])
    draw_plan(tmp_path / "p.png", SimpleNamespace(markers=[mesh]), SimpleNamespace(markers=[]), costs,
              (0.0, 0.2), (0.05, 0.05))
    ax, bx = figures[0].axes[:2]
    legend = {t.get_text(): h for t, h in zip(ax.get_legend().get_texts(), ax.get_legend().legend_handles)}
    mesh_handle = next(h for label, h in legend.items() if label.startswith("tissue mesh"))
    assert np.allclose(mesh_handle.get_facecolor()[:3], (0.9, 0.3, 0.3))  # filled as the mesh, not a grey line
    speeds = {t.get_text(): h for t, h in zip(bx.get_legend().get_texts(), bx.get_legend().legend_handles)
              if "m/s" in t.get_text()}
    assert len(speeds) == 2
    greys = {tuple(np.round(matplotlib.colors.to_rgba(h.get_color()), 3)) for h in speeds.values()}
    assert len(greys) == 1  # one neutral colour: the colour is the cost's, not the speed's
    assert {h.get_marker() for h in speeds.values()} == {"o", "^"}


def test_experiment_b_names_its_energy_unit(figures, tmp_path):
    from tissue_sim_ros.experiments import paper

    paper.experiment_b(tmp_path, angles_deg=(-10.0, -30.0), distance=0.02, progress=False)
    label = figures[0].axes[-1].get_ylabel()
    assert "energy" in label and "kg m^2" in label, label


def test_docs_images_exist_for_the_readme():
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    assert "](docs/img/accuracy.png)" in readme  # the speed-accuracy chart on the front page
    assert (Path(__file__).parents[1] / "docs" / "img" / "accuracy.png").is_file()
