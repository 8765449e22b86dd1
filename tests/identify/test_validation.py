import numpy as np
import pytest

from identify.validation import InvalidInputError, as_signal, positive, same_length


def test_as_signal_names_argument_and_first_bad_sample():
    with pytest.raises(InvalidInputError, match=r"u: sample 2 is nan \(2 non-finite"):
        as_signal("u", [0.0, 1.0, np.nan, np.inf])


def test_as_signal_rejects_wrong_shape_and_too_few_samples():
    with pytest.raises(InvalidInputError, match=r"y: expected a 1-D array, got shape \(2, 2\)"):
        as_signal("y", np.zeros((2, 2)))
    with pytest.raises(InvalidInputError, match="y: expected at least 5 samples, got 3"):
        as_signal("y", [1, 2, 3], min_samples=5)


def test_same_length_and_positive():
    assert same_length(u=np.zeros(3), y=np.zeros(3)) == 3
    with pytest.raises(InvalidInputError, match="u has 3, y has 4"):
        same_length(u=np.zeros(3), y=np.zeros(4))
    with pytest.raises(InvalidInputError, match="noise_bound_rad: expected a finite number > 0"):
        positive("noise_bound_rad", 0.0)
