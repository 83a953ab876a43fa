"""graphcal's test suite; its folders mirror the package."""
