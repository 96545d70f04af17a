"""What every benchmark says it ran on: the CPU's model among it, read from the kernel's list."""

from trainclimate.bench.common import cpu_model, machine


def test_the_cpu_model_is_the_first_model_name_the_kernel_lists(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text(
        "processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 7B13\n\n"
        "processor\t: 1\nmodel name\t: AMD EPYC 7B13\n"
    )
    assert cpu_model(str(info)) == "AMD EPYC 7B13"


def test_no_model_name_or_no_file_is_none(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t:   \nfeatures\t: fp asimd\n")
    assert cpu_model(str(info)) is None
    assert cpu_model(str(tmp_path / "missing")) is None


def test_every_result_names_the_model_of_this_machine():
    assert machine()["cpu_model"] == cpu_model()
    assert machine()["cores"] >= 1
