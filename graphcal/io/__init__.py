"""Files in and out: dataset folders (CSV/Parquet), OpenSky tables, ASTERIX
(CAT048/CAT021/CAT034 decoding and encoding, CAT063 export).
"""
