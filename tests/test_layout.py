"""Sensor layout: the SDH-2 default, pad selections, serialisation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from firmware_io.layout import LayoutError, MatrixInfo, SensorLayout


@pytest.fixture
def sdh2() -> SensorLayout:
    return SensorLayout.sdh2()


def test_sdh2_sizes_and_offsets(sdh2):
    assert sdh2.n_matrices == 6
    assert sdh2.n_taxels == 486
    assert [(m.cells_x, m.cells_y) for m in sdh2.matrices] == [(6, 14), (6, 13)] * 3
    assert sdh2.offsets == (0, 84, 162, 246, 324, 408)
    assert sdh2.matrix_slice(5) == slice(408, 486)


def test_distal_static_mask_has_68_taxels(sdh2):
    for i in (1, 3, 5):
        mask = sdh2.matrices[i].mask
        assert mask.sum() == 68
        assert not mask[:5, 0].any() and not mask[:5, 5].any()
        assert mask[5:, :].all() and mask[:, 1:5].all()
    for i in (0, 2, 4):
        assert sdh2.matrices[i].mask.all()
    whole = sdh2.static_mask()
    assert whole.shape == (486,) and whole.sum() == 3 * 84 + 3 * 68


def test_distal_mask_positions_in_wire_order(sdh2):
    # row-major, x fastest: row 0 of matrix 1 starts at 84; columns 0 and 5 of rows 0..4 are missing
    whole = sdh2.static_mask()
    missing = np.flatnonzero(~whole[84:162])
    expected = [r * 6 + c for r in range(5) for c in (0, 5)]
    assert missing.tolist() == expected


@pytest.mark.parametrize(
    ("selection", "pads"),
    [
        ("distal", (1, 3, 5)),
        ("proximal", (0, 2, 4)),
        ("all", (0, 1, 2, 3, 4, 5)),
        ("thumb-distal", (3,)),
        ("thumb", (2, 3)),
        ("finger-0-proximal", (0,)),
        ("1,3,5", (1, 3, 5)),
        (" 5, 1 ", (1, 5)),
        ([3], (3,)),
        (4, (4,)),
    ],
)
def test_pad_selections(sdh2, selection, pads):
    assert sdh2.pads(selection) == pads
    cols = sdh2.columns(selection)
    assert cols.dtype == np.int64
    expected = np.concatenate([np.arange(sdh2.offsets[p], sdh2.offsets[p] + sdh2.matrices[p].n_cells) for p in pads])
    assert np.array_equal(cols, expected)
    assert sdh2.pad_sizes(selection) == tuple(sdh2.matrices[p].n_cells for p in pads)


def test_distal_columns_count(sdh2):
    assert len(sdh2.columns("distal")) == 3 * 78
    assert len(sdh2.columns("proximal")) == 3 * 84
    assert np.array_equal(sdh2.columns("all"), np.arange(486))
    assert np.array_equal(sdh2.columns("thumb-distal"), np.arange(246, 324))


@pytest.mark.parametrize("selection", ["", "palm", "6", "1,1", "finger-x", "thumb-middle", [], [7], [-1], "1,,3"])
def test_bad_selections_raise(sdh2, selection):
    with pytest.raises(LayoutError):
        sdh2.columns(selection)


def test_dict_round_trip_through_json(sdh2):
    back = SensorLayout.from_dict(json.loads(json.dumps(sdh2.to_dict())))
    assert back == sdh2
    assert np.array_equal(back.static_mask(), sdh2.static_mask())
    assert [m.center for m in back.matrices] == [m.center for m in sdh2.matrices]


def test_from_dict_rejects_garbage():
    with pytest.raises(LayoutError):
        SensorLayout.from_dict({"nothing": 1})
    with pytest.raises(LayoutError):
        SensorLayout.from_dict({"matrices": [{"index": 0, "cells_x": "six", "cells_y": 2}]})


def test_subset_renumbers_and_keeps_masks(sdh2):
    sub = sdh2.subset("distal")
    assert sub.n_matrices == 3
    assert [m.index for m in sub.matrices] == [0, 1, 2]
    assert sub.n_taxels == 3 * 78
    assert sub.static_mask().sum() == 3 * 68
    frame = np.arange(486)
    assert np.array_equal(frame[sdh2.columns("distal")][sub.columns("all")], frame[sdh2.columns("distal")])


def test_matrix_checks():
    with pytest.raises(LayoutError):
        MatrixInfo(0, 0, 5)
    with pytest.raises(LayoutError):
        MatrixInfo(0, 6, 13, static_mask=np.ones((6, 13), bool))  # transposed
    with pytest.raises(LayoutError):
        SensorLayout((MatrixInfo(1, 6, 13),))  # index must match position
    with pytest.raises(LayoutError):
        SensorLayout(())


def test_from_matrix_infos_sorts_by_index():
    layout = SensorLayout.from_matrix_infos([MatrixInfo(1, 6, 13), MatrixInfo(0, 6, 14)])
    assert layout.offsets == (0, 84)


@pytest.mark.parametrize("fullscale", [1e308, -1e308, float("nan"), 0.0, 0.5, 4096.0, float("inf")])
def test_a_full_scale_no_12bit_pad_has_is_refused_where_it_enters(tmp_path, capsys, fullscale):
    """A recording's layout and a controller's matrix reply: 0 made the onset floor divide by zero in the
    daemon's hot path, 1e308 crashed ``handover dump replay://`` and the emulator (float32 overflow)."""
    import zipfile

    from firmware_io.emulator.frame_source import load_source
    from firmware_io.wire.errors import ProtocolError
    from firmware_io.wire.replies import MatrixInfoReply
    from runtime.cli import main

    with pytest.raises(LayoutError, match=r"^matrix 0: fullscale .* is not a 12-bit pad's full scale"):
        MatrixInfo(0, 6, 13, fullscale=fullscale)
    good = load_source("sim", seed=0, events=1).save(tmp_path / "good.hrec")
    bad = tmp_path / "bad.hrec"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "header.json":
                header = json.loads(data)
                header["layout"]["matrices"][0]["fullscale"] = fullscale
                data = json.dumps(header).encode()  # NaN and Infinity as Python's json writes them
            dst.writestr(item, data)
    assert main(["dump", f"replay://{bad}", "--frames", "3"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "matrix 0: fullscale" in err[0] and "from 1 to 4095" in err[0], err
    if abs(fullscale) != 1e308:  # a float32 reply cannot carry 1e308
        reply = MatrixInfoReply.decode(MatrixInfoReply(fullscale=fullscale).encode())
        with pytest.raises(ProtocolError, match=r"^matrix 2: controller reports fullscale .* from 1 to 4095"):
            reply.to_matrix_info(2)


@pytest.mark.parametrize("fullscale", [None, "abc", "4095", True, [1]])
def test_a_full_scale_that_is_not_a_number_in_a_header_is_named_as_such(fullscale):
    """A hand-edited header: null or a string said only what float() thinks, ``true`` read as 1."""
    row = {"index": 0, "cells_x": 6, "cells_y": 13, "fullscale": fullscale}
    with pytest.raises(LayoutError, match=r"^matrix 0: fullscale .* is not a 12-bit pad's full scale"):
        MatrixInfo.from_dict(row)
