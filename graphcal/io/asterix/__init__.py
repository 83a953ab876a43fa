"""ASTERIX: decoding CAT048/CAT021/CAT034 recordings into dataset tables, encoding them, and
the CAT063 sensor-bias export.
"""
