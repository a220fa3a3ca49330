"""The nuScenes side: tables, tokens, map expansion, conformance checks."""
