"""Files hdrd reads and writes: its file access, the drive logs and the unit's own files.

Reading untrusted files and writing atomically (:mod:`~hdrd.io.files.access`), a YAML key given
twice (:mod:`~hdrd.io.files.yamlkeys`), the bias file and the unit's state file
(:mod:`~hdrd.io.files.biasfile`, :mod:`~hdrd.io.files.unitstate`), drive logs as CSV and
Parquet, found by name (:mod:`~hdrd.io.files.drivelog`, :mod:`~hdrd.io.files.parquetlog`,
:mod:`~hdrd.io.files.drivefiles`), and other tools' CSV imported (:mod:`~hdrd.io.files.csvimport`).
"""
