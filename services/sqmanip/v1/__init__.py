"""Generated protobuf and gRPC modules (package sqmanip.v1). Do not edit: run
``python -m sqmanip.rpc.gen``."""
