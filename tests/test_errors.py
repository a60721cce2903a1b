from physics.errors import InputError, ObservationError


def test_message_names_file_line_field():
    e = ObservationError("must be finite", path="o.jsonl", line=3, field="objects.cup.position[1]")
    assert str(e) == "o.jsonl:3: objects.cup.position[1]: must be finite"
    assert isinstance(e, InputError) and isinstance(e, ValueError)
    assert str(InputError("bad", line=2)) == "line 2: bad"
