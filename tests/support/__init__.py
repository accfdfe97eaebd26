"""What the tests (and the end-to-end benches) share: private bus instances, process groups, a browser, a
WebRTC client. Not part of the installed package."""
