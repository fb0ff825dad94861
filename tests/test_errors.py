"""``jaxanom.errors``: bad input named by its argument, spelled by each caller in its own words."""
import pytest

from jaxanom.errors import InputError, reading

FLAG = {"min_count": "--min-count", "out": "--out", "overwrite": "--overwrite"}.get


def test_the_argument_leads_unless_the_message_places_it():
    error = InputError("out", "/x: folder exists; pass {overwrite}", mentions=("overwrite",))
    assert str(error) == "out /x: folder exists; pass overwrite"
    assert error.render(FLAG) == "--out /x: folder exists; pass --overwrite"
    assert InputError("min_count", ": must be >= 0").render(FLAG) == "--min-count: must be >= 0"
    assert InputError("out", " and {overwrite}: give one", mentions=("overwrite",)).render(FLAG) == \
        "--out and --overwrite: give one"
    placed = InputError("min_count", "the run diverged; lower {min_count}")
    assert (str(placed), placed.render(FLAG)) == ("the run diverged; lower min_count", "the run diverged; lower --min-count")
    assert isinstance(error, ValueError) and error.argument == "out"
    advice = InputError("min_count", ": 0 counts nothing; pass {min_count} 1")  # follows the name and repeats it
    assert advice.render(FLAG) == "--min-count: 0 counts nothing; pass --min-count 1"


def test_reading_names_the_argument_of_a_plain_value_error_and_passes_input_errors():
    with pytest.raises(InputError) as caught:
        with reading("out", "/x"):
            raise ValueError("not a run folder")
    assert (caught.value.argument, str(caught.value)) == ("out", "out /x: not a run folder")
    with pytest.raises(InputError) as caught:
        with reading("out"):
            raise ValueError("out: cannot join")  # the reader named it already: not twice
    assert caught.value.render(FLAG) == "--out: cannot join"
    with pytest.raises(InputError) as caught:
        with reading("out", "/x"):
            raise ValueError("/x: not a run folder")  # ... or the value
    assert caught.value.render(FLAG) == "--out /x: not a run folder"
    original = InputError("min_count", ": must be >= 0")
    with pytest.raises(InputError) as caught:
        with reading("out", "/x"):
            raise original
    assert caught.value is original
    with pytest.raises(TypeError):  # not bad input: a bug keeps its type
        with reading("out", "/x"):
            raise TypeError("a bug")
