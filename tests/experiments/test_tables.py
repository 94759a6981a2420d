import json

import torch

from ncs_lite.experiments.tables import write_table


def test_a_table_records_its_rows_provenance_and_thread_count(tmp_path):
    rows = [{"seed": 0, "ncs_4": 0.9}, {"seed": 1, "ncs_4": 0.8}]
    csv_path = write_table("demo", rows, {"episodes": 10}, out_dir=tmp_path)
    assert csv_path.read_text().splitlines() == ["seed,ncs_4", "0,0.9", "1,0.8"]
    table = json.loads((tmp_path / "demo.json").read_text())
    assert table["rows"] == rows and table["episodes"] == 10 and table["table"] == "demo"
    assert {"commit", "dirty"} <= set(table)
    assert table["threads"] == torch.get_num_threads()
