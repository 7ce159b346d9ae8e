"""The object dictionary of a CiA 402 drive as machlink uses it, built with the python
`canopen` package (shared by the interoperability scripts)."""

import canopen
from canopen.objectdictionary import ODRecord, ODVariable
from canopen.objectdictionary.datatypes import (
    INTEGER8, INTEGER16, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32, VISIBLE_STRING)


def var(index, sub, name, dtype, access="rw", default=0, pdo=False):
    v = ODVariable(name, index, sub)
    v.data_type = dtype
    v.access_type = access
    v.default = default
    v.pdo_mappable = pdo
    return v


def record(index, name, members):
    r = ODRecord(name, index)
    for m in members:
        r.add_member(m)
    return r


def drive_od(node):
    od = canopen.ObjectDictionary()
    od.add_object(var(0x1000, 0, "Device type", UNSIGNED32, "ro", 0x00020192))
    od.add_object(var(0x1001, 0, "Error register", UNSIGNED8, "ro", 0))
    od.add_object(var(0x1006, 0, "Communication cycle period", UNSIGNED32, "rw", 0))
    od.add_object(var(0x1008, 0, "Manufacturer device name", VISIBLE_STRING, "ro", "python canopen drive"))
    od.add_object(var(0x1017, 0, "Producer heartbeat time", UNSIGNED16, "rw", 0))
    for comm, cob in ((0x1400, 0x200 + node), (0x1800, 0x180 + node)):
        od.add_object(record(comm, "PDO communication", [
            var(comm, 0, "count", UNSIGNED8, "ro", 2),
            var(comm, 1, "COB-ID", UNSIGNED32, "rw", cob),
            var(comm, 2, "transmission type", UNSIGNED8, "rw", 255),
        ]))
    for mapping in (0x1600, 0x1A00):
        od.add_object(record(mapping, "PDO mapping", [var(mapping, 0, "count", UNSIGNED8, "rw", 0)]
                             + [var(mapping, s, "entry %d" % s, UNSIGNED32, "rw", 0) for s in range(1, 9)]))
    od.add_object(var(0x6040, 0, "Controlword", UNSIGNED16, "rw", 0, pdo=True))
    od.add_object(var(0x6041, 0, "Statusword", UNSIGNED16, "ro", 0x0240, pdo=True))
    od.add_object(var(0x605A, 0, "Quick stop option code", INTEGER16, "rw", 2))
    od.add_object(var(0x6060, 0, "Modes of operation", INTEGER8, "rw", 0, pdo=True))
    od.add_object(var(0x6061, 0, "Modes of operation display", INTEGER8, "ro", 0, pdo=True))
    od.add_object(var(0x6064, 0, "Position actual value", INTEGER32, "ro", 0, pdo=True))
    od.add_object(var(0x607A, 0, "Target position", INTEGER32, "rw", 0, pdo=True))
    od.add_object(record(0x60C1, "Interpolation data record", [
        var(0x60C1, 0, "count", UNSIGNED8, "ro", 1),
        var(0x60C1, 1, "set-point", INTEGER32, "rw", 0, pdo=True),
    ]))
    od.add_object(record(0x60C2, "Interpolation time period", [
        var(0x60C2, 0, "count", UNSIGNED8, "ro", 2),
        var(0x60C2, 1, "units", UNSIGNED8, "rw", 1),
        var(0x60C2, 2, "index", INTEGER8, "rw", -3),
    ]))
    od.add_object(var(0x60F4, 0, "Following error actual value", INTEGER32, "ro", 0, pdo=True))
    return od
