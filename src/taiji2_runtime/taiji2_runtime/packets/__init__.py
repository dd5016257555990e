"""CCSDS Space Packets: the raw-data contract as a spacecraft downlinks it (docs/interfaces.md).

* :mod:`.definition` - APIDs, fields, octet layout; :mod:`.cuc` - the CUC onboard time;
  :mod:`.time_correlation` - onboard -> contract time.
* Sample by sample (for nodes): :func:`.packetize.encode_packet` / :func:`.packetize.decode_packet`,
  :func:`.telecommand.encode_torque_tc` / :func:`.telecommand.decode_torque_tc`.
* Whole records: :func:`.bulk_encode.encode_streams`, :func:`.bulk_decode.decode_packet_buffers`;
  files: :func:`.files.read_packets`, :func:`.files.write_packets`, :func:`.files.is_packet_path`;
  bags: :mod:`.bag_io`.
"""
