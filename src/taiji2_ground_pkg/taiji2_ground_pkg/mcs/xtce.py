"""The packet definition as an XTCE database (CCSDS 660.0-B-2, XTCE 1.2), generated with ``yamcs-pymdb``.

Everything comes from the runtime's one packet definition (:mod:`taiji2_runtime.packets.definition`,
with the PUS constants of :mod:`~taiji2_runtime.packets.telecommand` and
:mod:`~taiji2_runtime.packets.scheduling`); nothing here restates a field layout by hand, and a test
decodes the project's packet files with the result (``space-packet-parser``) bit for bit.

Telemetry (``SequenceContainer``, root :data:`ROOT_CONTAINER`, abstract):

* the CCSDS primary header as flat parameters (``ccsds_version`` ... ``ccsds_packet_length``):
  ``space-packet-parser`` does not read pymdb's aggregate header (``yamcs.pymdb.ccsds``);
* one container per stream of :data:`~taiji2_runtime.packets.definition.STREAMS`, chosen by APID and
  the CUC P-field: the CUC secondary header (``cuc_pfield``, ``cuc_coarse`` [s], ``cuc_fine``
  [2^-24 s]), the user data (IEEE-754 binary64, big-endian, in the contract's units, named
  ``<stream>_<field>``) and the packet error control ``<stream>_crc`` (CRC-16-CCITT);
* the onboard executor's PUS-C verification reports TM[1,1], TM[1,7], TM[1,8] (APID 0x141): PUS-C TM
  secondary header, CUC time, the request id of the TC, the failure notice of TM[1,8], the CRC.

Telecommands (``MetaCommand``, PUS-C TC secondary header, APID 0x140): ``set_torque`` (TC[130,1]:
execution time, torque [N m], force [N]) and ``insert_activities`` (TC[11,4]: N, then N activities,
each its release time and its request, a whole TC[130,1] as 69 octets of binary).

The ground's own results (:mod:`.ground_parameters`: G and d of both GRS with their sigma, the link's
health) are local parameters with alarm ranges, set through Yamcs's API.

What XTCE (as pymdb writes it) does not carry, and who does it instead: the CRC is a plain 16-bit
parameter, checked by the receiving link (Yamcs: the packet preprocessor's ``errorDetection``
``CRC-16-CCIIT``; a reader of this file: compare it with the CRC of the octets before it); a TC's
sequence count, length and CRC are left to Yamcs's ``PusCommandPostprocessor`` (zeros here, CRC
appended); the activity's inner TC[130,1] (its own sequence count and CRC) cannot be built from XTCE
arguments, so it is binary, built by the planner's encoder; the CUC time is two integers (exact), not
an XTCE absolute time (Yamcs takes the packet time from its preprocessor, to 1 ms).
"""

from __future__ import annotations

import re
from pathlib import Path

from yamcs.pymdb import (
    AcceptedVerifier,
    AggregateArgument,
    AlgorithmCheck,
    ArgumentEntry,
    ArgumentValue,
    ArrayArgument,
    BinaryEncoding,
    BinaryMember,
    Command,
    CompleteVerifier,
    Container,
    EnumeratedParameter,
    Expression,
    FixedValueEntry,
    FloatArgument,
    FloatEncoding,
    FloatParameter,
    InputParameter,
    IntegerArgument,
    IntegerEncoding,
    IntegerMember,
    IntegerParameter,
    ParameterEntry,
    System,
    UnnamedJavaAlgorithm,
    all_of,
    any_of,
    eq,
)

from taiji2_ground_pkg.mcs.ground_parameters import add_ground_parameters
from taiji2_runtime.packets import definition as d
from taiji2_runtime.packets import scheduling, telecommand

__all__ = [
    "COMMAND_STAGES",
    "CRC_PARAMETER",
    "FAILURE_LABELS",
    "PRIMARY_HEADER",
    "REPORT_CONTAINERS",
    "ROOT_CONTAINER",
    "SYSTEM_NAME",
    "VERIFICATION_WINDOW_S",
    "VERIFIER_STAGES",
    "build_system",
    "parameter_name",
    "write_xtce",
    "xtce_document",
]

SYSTEM_NAME = "taiji2"
ROOT_CONTAINER = "ccsds_space_packet"
#: the flat CCSDS primary header (CCSDS 133.0-B-2): parameter name and bits, in order
PRIMARY_HEADER = (("ccsds_version", 3), ("ccsds_type", 1), ("ccsds_secondary_header", 1), ("ccsds_apid", 11),
                  ("ccsds_sequence_flags", 2), ("ccsds_sequence_count", 14), ("ccsds_packet_length", 16))
#: the packet error control parameter of a concrete container (its last entry; ``{container}`` its name)
CRC_PARAMETER = "{container}_crc"
#: the verification reports' containers: PUS subtype -> container name
REPORT_CONTAINERS = {1: "tm_1_1_acceptance_success", 2: "tm_1_2_acceptance_failure",
                     7: "tm_1_7_completion_success", 8: "tm_1_8_completion_failure"}
#: the command history stages of a TC[11,4], from the onboard reports (Yamcs ``Pus1Verifier``): name, the PUS
#: stage (its success subtype; the failure is the next one)
VERIFIER_STAGES = (("Acceptance", 1), ("Execution", 7))
#: every stage of a table's command history, in order: Yamcs's own (queue, link), then the verifiers'
COMMAND_STAGES = ("Queued", "Released", "Sent", *(name for name, _ in VERIFIER_STAGES))
#: how long after its release Yamcs waits for a stage [s]: the planner releases a run's tables at its start and
#: the ground station holds each until its pass, so a table's reports come up to a run's length later
VERIFICATION_WINDOW_S = 2 * 86400.0
#: the failure notice codes of TM[1,2] and TM[1,8] (:mod:`taiji2_runtime.packets.scheduling`) as operators read them
FAILURE_LABELS = {scheduling.FAILURE_LATE: "LATE", scheduling.FAILURE_CAPACITY: "SCHEDULE_FULL",
                  **{code: kind.upper() for kind, code in scheduling.ACCEPTANCE_FAILURE_CODES.items()}}

_UNSEGMENTED = 0b11
_TM, _TC = 0, 1
#: PUS-C (ECSS-E-ST-70-41C): the version number in the TC and TM secondary headers
_PUS_C = 2
#: the TCs' acknowledgement flags and source id (spacepackets' PusTc defaults, which the project uses)
_ACK_ALL = 0b1111
_SOURCE_ID = 0
_CUC_FINE_UNIT = f"2^-{8 * d.CUC_FINE_OCTETS} s"
assert sum(bits for _, bits in PRIMARY_HEADER) == 8 * d.PRIMARY_HEADER_OCTETS


def parameter_name(stream: d.StreamDefinition, field: str) -> str:
    """The XTCE name of a stream's user-data field (XTCE names exclude ``.``, ``[``, ``]``)."""
    return f"{stream.name}_" + re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", field)).strip("_")


def _uint(system: System, name: str, bits: int, description: str, units: str | None = None) -> IntegerParameter:
    return IntegerParameter(system, name, signed=False, bits=64 if bits > 32 else 32, units=units,
                            encoding=IntegerEncoding(bits=bits), short_description=description)


def _cuc_entries(system: System, prefix: str = "") -> list[ParameterEntry]:
    return [ParameterEntry(_uint(system, f"{prefix}cuc_pfield", 8,
                                 f"CUC P-field (0x{d.CUC_PFIELD:02X}: agency-defined epoch, "
                                 f"{d.CUC_COARSE_OCTETS}+{d.CUC_FINE_OCTETS} octets)")),
            ParameterEntry(_uint(system, f"{prefix}cuc_coarse", 8 * d.CUC_COARSE_OCTETS,
                                 "CUC coarse time: whole seconds since the onboard epoch", "s")),
            ParameterEntry(_uint(system, f"{prefix}cuc_fine", 8 * d.CUC_FINE_OCTETS,
                                 f"CUC fine time: fraction of a second in {_CUC_FINE_UNIT}", _CUC_FINE_UNIT))]


def _crc(system: System, container: str) -> ParameterEntry:
    # XTCE as pymdb writes it has no CRC of a TM packet (and pymdb 1.4 writes a parameter's ancillary data
    # outside its element): the CRC is the container's last parameter, named CRC_PARAMETER
    return ParameterEntry(_uint(system, CRC_PARAMETER.format(container=container), 8 * d.CRC_OCTETS,
                                "packet error control: CRC-16-CCITT (poly 0x1021, init 0xFFFF, no reflection, "
                                "no final xor) over every preceding octet of the packet"))


def _telemetry(system: System) -> None:
    header = {name: _uint(system, name, bits, f"CCSDS primary header: {name[6:].replace('_', ' ')}")
              for name, bits in PRIMARY_HEADER}
    root = Container(system, ROOT_CONTAINER, [ParameterEntry(p) for p in header.values()], abstract=True,
                     bits=8 * d.PRIMARY_HEADER_OCTETS,
                     short_description="CCSDS Space Packet (CCSDS 133.0-B-2) primary header, flat")
    apid = header["ccsds_apid"]
    # the conditions of a TM packet (flat: XTCE allows no ANDedConditions inside ANDedConditions)
    tm = [eq(header["ccsds_version"], 0), eq(header["ccsds_type"], _TM), eq(header["ccsds_secondary_header"], 1),
          eq(header["ccsds_sequence_flags"], _UNSEGMENTED)]
    # the streams' secondary header is the CUC field alone (a stream's container is chosen by APID and P-field);
    # a container's condition may name only what its bases parse (space-packet-parser evaluates it before)
    cuc = _cuc_entries(system)
    pfield = cuc[0].parameter
    streams = Container(system, "cuc_telemetry", cuc, base=root, abstract=True,
                        condition=all_of(*tm, any_of(*(eq(apid, s.apid) for s in d.STREAMS))),
                        short_description="telemetry of the raw-data streams: CUC secondary header")
    for stream in d.STREAMS:
        values = [ParameterEntry(FloatParameter(system, parameter_name(stream, field), bits=64,
                                                units=unit or None, encoding=FloatEncoding(bits=64),
                                                short_description=f"{stream.topic} {field}"))
                  for field, unit in zip(stream.fields, stream.units, strict=True)]
        Container(system, stream.name, [*values, _crc(system, stream.name)],
                  base=streams, condition=all_of(eq(apid, stream.apid), eq(pfield, d.CUC_PFIELD)),
                  bits=8 * stream.packet_octets,
                  short_description=f"APID 0x{stream.apid:03X}: {stream.topic}, {len(stream.fields)} x binary64")
    _reports(system, root, tm, apid)


def _reports(system: System, root: Container, tm: list[Expression], apid: IntegerParameter) -> None:
    """TM[1,1|7|8] of the onboard executor (APID ``REPORT_APID``): PUS-C TM secondary header, CUC time,
    request id; TM[1,8] adds its failure notice (code, activities refused)."""
    pus = [("pus_version", 4, "PUS version (2: PUS-C)"), ("pus_time_reference_status", 4, "spacecraft time "
           "reference status"), ("pus_service", 8, "service type"), ("pus_subtype", 8, "message subtype"),
           ("pus_message_counter", 16, "message type counter"), ("pus_destination_id", 16, "destination id")]
    entries = {name: _uint(system, name, bits, f"PUS-C TM secondary header: {text}") for name, bits, text in pus}
    # the request id (the TC's packet id and sequence control) as its fields: Yamcs's verifiers match the
    # report's APID and sequence count with the command's
    request = [("request_ccsds_version", 3, "version"), ("request_ccsds_type", 1, "type (1: TC)"),
               ("request_ccsds_secondary_header", 1, "secondary header flag"), ("request_apid", 11, "APID"),
               ("request_sequence_flags", 2, "sequence flags"), ("request_sequence_count", 14, "sequence count")]
    requests = [_uint(system, name, bits, f"request id of the TC reported on: {text}") for name, bits, text in request]
    cuc = _cuc_entries(system, "report_")
    pfield = cuc[0].parameter
    base = Container(system, "pus_verification_report",
                     [*(ParameterEntry(p) for p in entries.values()), *cuc,
                      *(ParameterEntry(p) for p in requests)],
                     base=root, abstract=True,
                     condition=all_of(*tm, eq(apid, scheduling.REPORT_APID)),
                     short_description=f"APID 0x{scheduling.REPORT_APID:03X}: PUS-C TM[1,x] verification report")
    code = EnumeratedParameter(system, "failure_code", sorted(FAILURE_LABELS.items()),
                               encoding=IntegerEncoding(bits=8),
                               short_description="failure notice code: TM[1,8] LATE (a release time before the "
                                                 "table's arrival plus the time margin) or SCHEDULE_FULL; TM[1,2] "
                                                 "the defect of a TC refused at acceptance")
    failure = [ParameterEntry(code),
               ParameterEntry(_uint(system, "failure_refused", 16, "failure notice data: TM[1,8] activities refused "
                                                                   "(TM[1,2]: 0)"))]
    for subtype, name in REPORT_CONTAINERS.items():
        Container(system, name, [*(failure if subtype in (2, 8) else []), _crc(system, name)], base=base,
                  condition=all_of(eq(entries["pus_version"], _PUS_C), eq(entries["pus_service"], 1),
                                   eq(entries["pus_subtype"], subtype), eq(pfield, d.CUC_PFIELD)),
                  short_description=f"PUS TM[1,{subtype}]")


def _pus_tc(system: System, name: str, service: int, subtype: int, arguments: list, entries: list,
            description: str) -> Command:
    """A PUS-C TC of APID ``TC_APID``: the primary header (sequence count and length 0: the link's
    postprocessor fills them and appends the CRC), the PUS-C TC secondary header, then ``entries``."""
    # the APID is an argument (of one allowed value, its default) so that the verifiers can read it
    apid = IntegerArgument("apid", signed=False, minimum=d.TC_APID, maximum=d.TC_APID, default=d.TC_APID,
                           encoding=IntegerEncoding(bits=11), short_description="APID of the onboard executor")
    fixed = [FixedValueEntry(f"{0:02x}", "ccsds_version", bits=3), FixedValueEntry(f"{_TC:02x}", "ccsds_type", bits=1),
             FixedValueEntry("01", "ccsds_secondary_header", bits=1), ArgumentEntry(apid),
             FixedValueEntry(f"{_UNSEGMENTED:02x}", "ccsds_sequence_flags", bits=2),
             FixedValueEntry("0000", "ccsds_sequence_count", bits=14,
                             short_description="set by the link's postprocessor"),
             FixedValueEntry("0000", "ccsds_packet_length", bits=16,
                             short_description="set by the link's postprocessor"),
             FixedValueEntry(f"{_PUS_C:02x}", "pus_version", bits=4),
             FixedValueEntry(f"{_ACK_ALL:02x}", "pus_ack_flags", bits=4),
             FixedValueEntry(f"{service:02x}", "pus_service", bits=8),
             FixedValueEntry(f"{subtype:02x}", "pus_subtype", bits=8),
             FixedValueEntry(f"{_SOURCE_ID:04x}", "pus_source_id", bits=16)]
    return Command(system, name, arguments=[apid, *arguments], entries=[*fixed, *entries],
                   short_description=f"PUS-C TC[{service},{subtype}] APID 0x{d.TC_APID:03X}: {description}",
                   long_description="The CRC-16-CCITT is appended, and the sequence count and length set, by "
                                    "the TC link's postprocessor (Yamcs: org.yamcs.pus.PusCommandPostprocessor "
                                    "with errorDetection CRC-16-CCIIT).")


def _telecommands(system: System) -> None:
    fixed_pfield = FixedValueEntry(f"{d.CUC_PFIELD:02x}", "execute_cuc_pfield", bits=8)
    coarse = IntegerArgument("execute_cuc_coarse", signed=False, units="s",
                             encoding=IntegerEncoding(bits=8 * d.CUC_COARSE_OCTETS),
                             short_description="execution time (onboard), CUC coarse: whole seconds")
    fine = IntegerArgument("execute_cuc_fine", signed=False, units=_CUC_FINE_UNIT,
                           encoding=IntegerEncoding(bits=8 * d.CUC_FINE_OCTETS),
                           short_description="execution time (onboard), CUC fine")
    # the executed-torque stream's fields are the command's values (torque then force, CRF)
    torque_stream = next(s for s in d.STREAMS if s.name == "executed_torque")
    values = [FloatArgument(parameter_name(torque_stream, f).removeprefix(f"{torque_stream.name}_"), bits=64,
                            units=u, encoding=FloatEncoding(bits=64), short_description=f"{f} (CRF)")
              for f, u in zip(torque_stream.fields, torque_stream.units, strict=True)]
    assert 8 + 8 * len(values) == telecommand.TC_APP_DATA_OCTETS
    _pus_tc(system, "set_torque", d.TC_SERVICE, d.TC_SUBTYPE_TORQUE, [coarse, fine, *values],
            [fixed_pfield, ArgumentEntry(coarse), ArgumentEntry(fine), *(ArgumentEntry(v) for v in values)],
            "set torque and force from the execution time on")
    count = IntegerArgument("N", signed=False, minimum=1, maximum=scheduling.MAX_ACTIVITIES_PER_TC,
                            encoding=IntegerEncoding(bits=16), short_description="number of activities")
    activity = AggregateArgument("activity", members=[
        IntegerMember("release_cuc_pfield", signed=False, minimum=d.CUC_PFIELD, maximum=d.CUC_PFIELD,
                      encoding=IntegerEncoding(bits=8), short_description=f"CUC P-field: 0x{d.CUC_PFIELD:02X}"),
        IntegerMember("release_cuc_coarse", signed=False, units="s",
                      encoding=IntegerEncoding(bits=8 * d.CUC_COARSE_OCTETS),
                      short_description="release time (onboard), CUC coarse"),
        IntegerMember("release_cuc_fine", signed=False, units=_CUC_FINE_UNIT,
                      encoding=IntegerEncoding(bits=8 * d.CUC_FINE_OCTETS),
                      short_description="release time (onboard), CUC fine"),
        BinaryMember("request", min_length=telecommand.TC_PACKET_OCTETS, max_length=telecommand.TC_PACKET_OCTETS,
                     encoding=BinaryEncoding(bits=8 * telecommand.TC_PACKET_OCTETS),
                     short_description="the whole TC[130,1] set_torque (with its own sequence count and CRC), "
                                       "its execution time = the release time")])
    activities = ArrayArgument("activities", activity, length=ArgumentValue(count),
                               short_description="the N instructions")
    table = _pus_tc(system, "insert_activities", scheduling.SCHEDULING_SERVICE, scheduling.INSERT_ACTIVITIES,
                    [count, activities], [ArgumentEntry(count), ArgumentEntry(activities)],
                    "insert activities into the time-based schedule")
    _add_verifiers(table)


def _add_verifiers(command: Command) -> None:
    """The command history's Acceptance and Execution stages of ``command`` from the onboard TM[1,1|2] and
    TM[1,7|8]: Yamcs's ``org.yamcs.pus.Pus1Verifier`` matches a report to the command by the APID (the
    command's argument) and the sequence count (Yamcs's postprocessor puts it in the command history,
    ``ccsds-seqcount``) and passes or fails the stage; a failure's message names the onboard reason."""
    def check(stage: int) -> AlgorithmCheck:
        # Pus1Verifier takes its first five inputs by position: sent APID, sent count, report APID, report
        # count, report subtype
        inputs = [InputParameter("/yamcs/cmd/arg/apid", name="sentApid"),
                  InputParameter("/yamcs/cmdHist/ccsds-seqcount", name="sentSeq"),
                  InputParameter(f"/{SYSTEM_NAME}/request_apid", name="rcvdApid"),
                  InputParameter(f"/{SYSTEM_NAME}/request_sequence_count", name="rcvdSeq"),
                  InputParameter(f"/{SYSTEM_NAME}/pus_subtype", name="subtype"),
                  InputParameter(f"/{SYSTEM_NAME}/failure_code", name="failure_code"),
                  InputParameter(f"/{SYSTEM_NAME}/failure_refused", name="failure_refused")]
        template = ("refused at acceptance onboard: {failure_code}" if stage == 1 else
                    "refused onboard: {failure_code}, {failure_refused} activities not scheduled")
        return AlgorithmCheck(UnnamedJavaAlgorithm(
            f'org.yamcs.pus.Pus1Verifier({{stage: {stage}, template: "{template}"}})', inputs=inputs))

    (acceptance, _), (execution, _) = VERIFIER_STAGES
    command.accepted_verifier = AcceptedVerifier(check(1), VERIFICATION_WINDOW_S, name=acceptance)
    command.complete_verifiers.append(CompleteVerifier(check(7), VERIFICATION_WINDOW_S, name=execution))


def build_system() -> System:
    """The pymdb ``System`` of every TM APID and the PUS-C TCs (see the module docstring)."""
    system = System(SYSTEM_NAME, short_description="Taiji-2 raw-data contract as CCSDS Space Packets "
                                                   "(docs/interfaces.md, CCSDS Space Packets)")
    _telemetry(system)
    _telecommands(system)
    add_ground_parameters(system)
    return system


def xtce_document() -> str:
    """The XTCE 1.2 document (XML text)."""
    text = build_system().dumps(top_comment="Generated by taiji2_ground_pkg.mcs.xtce (yamcs-pymdb) from "
                                            "taiji2_runtime.packets.definition: do not edit")
    return _execution_after_acceptance(_name_verifier_algorithms(text))


def _name_verifier_algorithms(text: str) -> str:
    """pymdb 1.4 names every verifier's algorithm "Unnamed", and Yamcs refuses a command whose two verifiers
    run algorithms of one name ("already active"): each becomes ``<command>_<verifier>``."""
    def command(match: re.Match) -> str:
        name = match.group(1)
        return re.sub(r'(<(\w+Verifier) name="(\w+)">(?:(?!</\2>).)*?<CustomAlgorithm name=")Unnamed"',
                      lambda m: f'{m.group(1)}{name}_{m.group(3)}"', match.group(0), flags=re.DOTALL)

    return re.sub(r'<MetaCommand name="(\w+)".*?</MetaCommand>', command, text, flags=re.DOTALL)


def _execution_after_acceptance(text: str) -> str:
    """The Execution verifier's window starts when Acceptance passes (XTCE ``timeLastVerifierPassed``; pymdb 1.4
    writes every window from the command's release). Yamcs stops a command's verifiers once one completes it:
    with both started at release, a table whose TM[1,1] was lost and TM[1,7] came was complete with Acceptance
    never passed, and the TM[1,1]'s second copy (the onboard executor sends each report twice) came too late.
    Chained, the lone TM[1,7] is not yet looked for, and the second copies pass both stages."""
    _, (execution, _) = VERIFIER_STAGES
    chained, n = re.subn(rf'(<CompleteVerifier name="{execution}">(?:(?!</CompleteVerifier>).)*?<CheckWindow [^>]*?'
                         r'timeWindowIsRelativeTo=")commandRelease"', r'\1timeLastVerifierPassed"', text,
                         flags=re.DOTALL)
    if n == 0:
        raise RuntimeError("XTCE: no Execution verifier window to chain to Acceptance (pymdb's output changed)")
    return chained


def write_xtce(path: str | Path) -> Path:
    """Write the XTCE document to ``path`` (a temporary file, then a rename) and return the path.

    Raises
    ------
    OSError
        If it cannot be written.
    """
    path = Path(path)
    text = xtce_document()
    temporary = path.with_name(f".{path.name}.partial")
    try:
        temporary.write_text(text, encoding="utf-8")
        temporary.replace(path)
    finally:
        temporary.unlink(missing_ok=True)
    return path
