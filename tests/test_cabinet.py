import numpy as np
import pytest

from sb3_memret.tasks.drawer.cabinet import LAYERS, CabinetLayout, check_layer


def test_layers_are_stacked_top_to_bottom_without_overlap():
    lay = CabinetLayout()
    boxes = [lay.inner_box(layer) for layer in LAYERS]
    for (low_a, high_a), (low_b, high_b) in zip(boxes, boxes[1:]):
        assert low_a[2] > high_b[2]  # layer k sits above layer k + 1
    for low, high in boxes:
        assert np.all(high > low)
        assert high[2] < lay.top_z


def test_opening_moves_box_and_handle_towards_robot():
    lay = CabinetLayout()
    for layer in LAYERS:
        (low0, high0), (low1, high1) = lay.inner_box(layer), lay.inner_box(layer, 0.2)
        np.testing.assert_allclose(low1 - low0, [-0.2, 0, 0])
        np.testing.assert_allclose(high1 - high0, [-0.2, 0, 0])
        np.testing.assert_allclose(lay.handle_center(layer, 0.2) - lay.handle_center(layer), [-0.2, 0, 0])
        assert lay.handle_center(layer)[0] < lay.front_x


@pytest.mark.parametrize("bad", [0, 4, -1, 2.0, "2", True, None])
def test_check_layer_names_accepted_values(bad):
    with pytest.raises(ValueError, match=r"drawer layer must be one of \[1, 2, 3\]"):
        check_layer(bad)


def test_check_layer_accepts_numpy_ints():
    assert check_layer(np.int64(3)) == 3
