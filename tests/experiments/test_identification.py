"""`slip reproduce identification`: hidden sets recovered in-process, rendered, pictures drawn."""
from incipient_slip.experiments import identification
from incipient_slip.experiments.settings import Settings


def test_one_hidden_set_is_recovered_rendered_and_drawn(tmp_path):
    settings = Settings(budget="quick", work=tmp_path, options={"sets": 1})
    results = identification.run(settings)
    row = results["rows"][0]
    assert results["sets"] == 1 and abs(row["k_b"][1] / row["k_b"][0] - 1) < 0.1
    assert row["figures"] == ["identification_lag.png", "identification_stiffness.png"]
    assert all((settings.figures / name).is_file() for name in row["figures"])
    block = identification.render(results)["identification-recovery"]
    assert "| 0 | " in block and "largest error over the 1 sets" in block
