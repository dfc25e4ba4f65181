# Drive headless Chromium (SwiftShader WebGL) to open the MCAP in Lichtblick web and screenshot it.
# usage: shot.py URL OUT.png [SECONDS_TO_WAIT]
import sys, tempfile, time
from selenium import webdriver
from selenium.webdriver.chrome.service import Service
url, out, wait = sys.argv[1], sys.argv[2], float(sys.argv[3]) if len(sys.argv) > 3 else 40
o = webdriver.ChromeOptions()
o.binary_location = "/usr/bin/chromium"
for a in ["--headless=new", "--no-sandbox", "--window-size=1600,1000", "--use-angle=swiftshader",
          "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--user-data-dir=" + tempfile.mkdtemp()]:
    o.add_argument(a)
o.set_capability("goog:loggingPrefs", {"browser": "ALL"})
d = webdriver.Chrome(options=o, service=Service("/usr/bin/chromedriver"))
d.set_window_size(1600, 1000)
d.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {"width": 1600, "height": 1000, "deviceScaleFactor": 1, "mobile": False})
d.get(url)
time.sleep(wait)
d.save_screenshot(out)
for e in d.get_log("browser")[-40:]:
    print(e["level"], e["message"][:300])
print("title:", d.title)
d.quit()
