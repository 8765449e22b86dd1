"""Wire-level pieces shared by the driver and the simulated devices: codecs, object dictionaries,
config validation and the error tree. Imports only ``identify`` data types."""
