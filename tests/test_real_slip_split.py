"""real_slip's split (trainer.real_tasks): blocked temporal folds over each file's contact chunks."""

import numpy as np
import pytest

from trainer.real_tasks import temporal_blocks


def _toy():
    chunks = np.array(["a#0"] * 3 + ["a#1"] * 2 + ["a#2"] * 2 + ["b#0"] * 4 + ["b#1"] * 1)
    y = np.array([c[0] for c in chunks])
    return y, chunks


def test_blocks_follow_time_order_and_keep_chunks_whole():
    y, chunks = _toy()
    blocks = temporal_blocks(y, chunks, 3)
    assert blocks.tolist() == [0, 0, 0, 1, 1, 2, 2, 0, 0, 0, 0, 1]  # class b has 2 chunks: no third block
    for c in set(chunks):
        assert len(set(blocks[chunks == c])) == 1


@pytest.mark.realdata
def test_real_slip_tests_every_chunk_once_and_trains_every_class():
    from tests.conftest import real_data_dir
    from trainer.real_tasks import real_tasks

    task = next(t for t in real_tasks(real_data_dir().parent)[0] if t.name == "real_slip")
    tested = np.concatenate([s.test for s in task.splits])
    assert sorted(tested.tolist()) == list(range(len(task.y)))  # every window tested exactly once
    for s in task.splits:
        assert not set(task.chunks[s.train]) & set(task.chunks[s.test])
        assert set(task.y[s.train]) == set(task.y)


def test_real_objects_long_names_the_objects_it_leaves_out():
    """Objects with too few contact chunks for 5 folds are left out; the rule names them (it did not)."""
    from tests.conftest import real_data_dir
    from trainer.real_tasks import LONG_FOLDS, real_tasks

    data = real_data_dir()
    task = next(t for t in real_tasks(data.parent)[0] if t.name == "real_objects_long")
    profiles = data / "kiechle" / "pressure_profiles"
    same = {"foam_ball": "foam", "hockey_ball": "hockey"}
    recorded = {same.get(p.stem, p.stem) for folder in ("classification_video", "grasps")
                for p in (profiles / folder).glob("*.dsa")}
    left_out = sorted(recorded - set(task.y.tolist()))
    assert f"at least {LONG_FOLDS} contact chunks" in task.split_rule
    if left_out:
        assert f"(left out: {', '.join(left_out)})" in task.split_rule
    else:
        assert "left out" not in task.split_rule
