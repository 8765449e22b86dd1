"""Test FMUs: Python sources that ``pythonfmu build`` turns into FMI 2.0 co-simulation FMUs at test time
(``tests/conftest.py``), so no binary FMU is kept in the repository."""
